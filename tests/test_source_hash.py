"""The numba cache key (`reference_sim.SOURCE_HASH`) covers every source file the simulator
compiles, subfolders and `rigidmath` included: an edit anywhere in them must never leave a stale
compiled function."""

import shutil
from pathlib import Path

import pytest

import reference_sim
from reference_sim import COMPILED_PACKAGES, SOURCE_FILES, source_hash

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
