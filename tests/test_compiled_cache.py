"""Where the compiled code is kept (`reference_sim/compiled_cache.py`). The numba cache key
(`reference_sim.SOURCE_HASH`) covers every source file the simulator compiles, subfolders and
`rigidmath` included: an edit anywhere in them must never leave a stale compiled function. Old
versions' directories are removed beyond the most recently used few, and nothing else is."""

import io
import os
import shutil
from pathlib import Path

import pytest
from rich.console import Console

import reference_sim
from comparators import sweep
from reference_sim import COMPILED_PACKAGES, SOURCE_FILES, source_hash
from reference_sim.compiled_cache import KEPT_VERSIONS, is_compiled, mark_or_prune

PACKAGE = Path(reference_sim.__file__).parent
ROOT = PACKAGE.parent


def test_every_python_file_under_the_packages_is_hashed():
    hashed = {p.relative_to(ROOT).as_posix() for p in SOURCE_FILES}
    every = {p.relative_to(ROOT).as_posix() for d in COMPILED_PACKAGES for p in d.rglob("*.py")}
    assert hashed == every
    assert "reference_sim/contact/gauss_seidel.py" in hashed  # a subfolder's
    assert "rigidmath/quaternion.py" in hashed  # the formulas the kernels compile


def _copy(tmp_path):
    for package in COMPILED_PACKAGES:
        shutil.copytree(
            package, tmp_path / package.name, ignore=shutil.ignore_patterns("__pycache__")
        )
    return [tmp_path / package.name for package in COMPILED_PACKAGES]


@pytest.mark.parametrize("edited", ["reference_sim/contact/settings.py", "rigidmath/quaternion.py"])
def test_an_edit_in_any_compiled_file_changes_the_hash(tmp_path, edited):
    copies = _copy(tmp_path)
    before = source_hash(*copies)
    assert before == reference_sim.SOURCE_HASH
    path = tmp_path / edited
    path.write_text(path.read_text() + "\n# an edit\n")
    assert source_hash(*copies) != before


def test_a_new_file_in_a_subfolder_changes_the_hash(tmp_path):
    copies = _copy(tmp_path)
    before = source_hash(*copies)
    (tmp_path / "reference_sim" / "contact" / "extra.py").write_text("X = 1\n")
    assert source_hash(*copies) != before


def _versions(base: Path, count: int) -> list[Path]:
    """`count` version directories under `base`, each holding a file, the last most recently
    used."""
    versions = [base / f"{k:016x}" for k in range(count)]
    for age, path in enumerate(reversed(versions)):
        path.mkdir()
        (path / "code.nbi").write_bytes(b"")
        os.utime(path, (1e9 - age, 1e9 - age))
    return versions


def test_a_new_version_removes_all_but_the_most_recently_used_others(tmp_path):
    versions = _versions(tmp_path, KEPT_VERSIONS + 2)
    (tmp_path / "another_project").mkdir()  # a shared NUMBA_CACHE_DIR: not a version
    (tmp_path / "0123456789abcdef.txt").write_text("")  # named like one, but a file
    removed = mark_or_prune(tmp_path, "f" * 16)
    kept = versions[-(KEPT_VERSIONS - 1) :]
    assert sorted(removed) == sorted(set(versions) - set(kept))
    left = {p.name for p in tmp_path.iterdir()}
    assert left == {p.name for p in kept} | {"another_project", "0123456789abcdef.txt"}


def test_a_version_in_use_is_marked_and_removes_nothing(tmp_path):
    versions = _versions(tmp_path, KEPT_VERSIONS + 2)
    oldest = versions[0]
    assert mark_or_prune(tmp_path, oldest.name) == []
    assert all(p.is_dir() for p in versions)
    newest = max(tmp_path.iterdir(), key=lambda p: p.stat().st_mtime)
    assert newest == oldest  # now the most recently used: kept when the next version comes


@pytest.mark.parametrize("compiled", [True, False])
def test_the_compile_stage_says_whether_it_compiles_or_loads(monkeypatch, compiled):
    """The session compiled the simulator (conftest): `is_compiled` says so. Told it is not,
    `warm_up` says it compiles, in parallel processes that find numba's cache filled."""
    assert is_compiled()
    monkeypatch.setattr(sweep, "is_compiled", lambda: compiled)
    out = io.StringIO()
    sweep.warm_up(["reference"], Console(file=out))
    assert out.getvalue() == (sweep.LOADING if compiled else sweep.COMPILING) + "\n"
    out = io.StringIO()
    sweep.warm_up(["mujoco"], Console(file=out))
    assert out.getvalue() == ""  # no reference, no stage
