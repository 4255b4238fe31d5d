"""The numba cache key (`reference_sim.SOURCE_HASH`) covers every source file of the simulator,
subfolders included: an edit anywhere in it must never leave a stale compiled function."""

import shutil
from pathlib import Path

import reference_sim
from reference_sim import SOURCE_FILES, source_hash

PACKAGE = Path(reference_sim.__file__).parent


def test_every_python_file_under_the_package_is_hashed():
    hashed = {p.relative_to(PACKAGE).as_posix() for p in SOURCE_FILES}
    every = {p.relative_to(PACKAGE).as_posix() for p in PACKAGE.rglob("*.py")}
    assert hashed == every
    assert "contact/gauss_seidel.py" in hashed  # a subfolder's


def test_an_edit_in_a_subfolder_changes_the_hash(tmp_path):
    copy = tmp_path / "reference_sim"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    before = source_hash(copy)
    assert before == reference_sim.SOURCE_HASH
    edited = copy / "contact" / "settings.py"
    edited.write_text(edited.read_text() + "\n# an edit\n")
    assert source_hash(copy) != before


def test_a_new_file_in_a_subfolder_changes_the_hash(tmp_path):
    copy = tmp_path / "reference_sim"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    before = source_hash(copy)
    (copy / "contact" / "extra.py").write_text("X = 1\n")
    assert source_hash(copy) != before
