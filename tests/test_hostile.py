"""The hostile corpus (issue 34, item 8): every input of tests/hostile/corpus.toml, given to
`reports.cli.main` in-process, gets its exit status; a refused one (exit 2) gets exactly one line
on stderr naming what is wrong, no traceback, nothing on stdout; and no input writes anything.

An entry is a table `[[input]]`: `name`, `argv` (placeholders `{files}`, `{tmp}`, `{huge}`,
`{fifo}`, see the corpus's header), `exit`, `says` (a substring of the error line, or a list of
them; required for exit 2, and found in what the line says besides the paths given in argv),
optionally `env` (environment variables set for the call) and `xfail` (why the input still
fails: the test then xfails strictly, so a fix shows as XPASS).
"""

import os
import tomllib
from pathlib import Path

import pytest

from reports.cli import main

HOSTILE = Path(__file__).resolve().parent / "hostile"
FILES = HOSTILE / "files"
CORPUS = tomllib.loads((HOSTILE / "corpus.toml").read_text(encoding="utf-8"))["input"]
HUGE_BYTES = 2**30


@pytest.fixture(scope="module")
def special(tmp_path_factory) -> dict[str, str]:
    """The files too big or too special to commit: a sparse 1 GiB file and a FIFO."""
    where = tmp_path_factory.mktemp("special")
    huge = where / "huge.toml"
    with huge.open("wb") as file:
        file.truncate(HUGE_BYTES)
    fifo = where / "fifo.toml"
    os.mkfifo(fifo)
    return {"huge": str(huge), "fifo": str(fifo)}


def listing(root: Path) -> dict[str, tuple[int, int]]:
    """Every path under `root` with its size and modification time."""
    found = {}
    for path in sorted(root.rglob("*")):
        info = path.lstat()
        found[str(path.relative_to(root))] = (info.st_size, info.st_mtime_ns)
    return found


@pytest.mark.parametrize(
    "entry",
    [
        pytest.param(e, marks=pytest.mark.xfail(reason=e["xfail"], strict=True))
        if "xfail" in e
        else e
        for e in CORPUS
    ],
    ids=[e["name"] for e in CORPUS],
)
def test_hostile_input(entry, special, tmp_path, monkeypatch, capsys):
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    for name, value in entry.get("env", {}).items():
        monkeypatch.setenv(name, value)
    fill = {"files": str(FILES), "tmp": str(cwd), **special}
    argv = [arg.format(**fill) for arg in entry["argv"]]
    before = listing(FILES)
    capsys.readouterr()
    try:
        status = main(argv)
    except SystemExit as exc:  # argparse's errors
        status = exc.code
    out, err = capsys.readouterr()
    assert status == entry["exit"], err
    assert "Traceback" not in out + err
    if entry["exit"] == 2:
        assert out == ""
        assert err.endswith("\n") and err.count("\n") == 1, err
        assert "error:" in err
        # `says` must be found in what the message says, not in the path it echoes
        said = err
        for raw, arg in zip(entry["argv"], argv, strict=True):
            if raw != arg:
                said = said.replace(arg, "PATH")
        says = entry["says"]
        for part in [says] if isinstance(says, str) else says:
            assert part in said, err
    assert list(cwd.iterdir()) == [], "the command left files behind"
    assert listing(FILES) == before, "the command changed tests/hostile/files"


def test_corpus_is_complete():
    names = [e["name"] for e in CORPUS]
    assert len(names) >= 150
    assert len(set(names)) == len(names), "names must be unique"
    for e in CORPUS:
        assert set(e) <= {"name", "argv", "exit", "says", "env", "xfail"}, e["name"]
        assert e["exit"] in (0, 2), e["name"]
        assert e["exit"] != 2 or e.get("says"), f"{e['name']}: exit 2 needs `says`"
    used = " ".join(arg for e in CORPUS for arg in e["argv"])
    for path in sorted(FILES.rglob("*")):
        relative = path.relative_to(FILES)
        assert any(f"{{files}}/{part}" in used for part in [relative, *relative.parents][:-1]), (
            f"{relative} is used by no entry"
        )
