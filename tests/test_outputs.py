"""Every output path is checked before any work: a bad one is one line, exit 2, nothing written
(issue 34: outputs). In-process through `reports.cli.main`, in a temporary working directory
holding a directory `adir`, a file `afile` and a directory named like a file, `dir.csv`."""

import pytest

from reports.cli import main

EXIT_BAD_INPUT = 2
# /proc takes no new file, /sys refuses one: places a path check by permissions alone would pass
UNWRITABLE = ("/proc", "/sys")

CASES = [
    (["run", "free_spin_cube", "--engine", "mujoco", "--out", "dir.csv"], "is a directory"),
    (["run", "free_spin_cube", "--engine", "mujoco", "--out", "nope/x.csv"], "missing"),
    (["bench", "--cases", "free_spin_cube", "--out", "dir.csv"], "is a directory"),
    (["animate", "free_spin_cube", "--out", "nope/a.gif"], "missing"),
    (["report", "--quick", "--out", "afile"], "is a file"),
    (["report", "--quick", "--out", "nope/deeper"], "missing"),
    (["report", "--quick", "--cache", "afile"], "is a file"),
    (["gate", "g.toml", "--junit", "nope/j.xml"], "missing"),
    (["gate", "--record", "nope/g.toml", "--cases", "x", "--engine", "mujoco"], "missing"),
    *[
        (["run", "free_spin_cube", "--engine", "mujoco", "--out", f"{place}/x.csv"], "cannot write")
        for place in UNWRITABLE
    ],
    (["report", "--quick", "--out", "/proc/rigidbench"], "cannot write"),
    (["animate", "free_spin_cube", "--out", "/sys/a.gif"], "cannot write"),
    (["gate", "--record", "/proc/g.toml", "--cases", "x", "--engine", "mujoco"], "cannot write"),
]


@pytest.mark.parametrize("argv, said", CASES, ids=[" ".join(a) for a, _ in CASES])
def test_a_bad_output_path_is_one_line_and_nothing_written(
    argv, said, tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "adir").mkdir()
    (tmp_path / "dir.csv").mkdir()
    (tmp_path / "afile").write_text("")
    (tmp_path / "g.toml").write_text("")
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert main(argv) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rigidbench: error: ") and said in err[0], err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
