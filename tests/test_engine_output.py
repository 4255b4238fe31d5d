"""What an engine says while it runs: captured from C, Python and warnings into the run's
record (`RunMeta.messages`, the failure reason), never onto the terminal."""

import ctypes
import dataclasses
import os
import sys
import warnings

import pytest

from cases import CATALOG
from comparators import Trajectory, run
from comparators import engine as registry
from comparators.engine_output import (
    MAX_MESSAGE_CHARS,
    MAX_MESSAGES,
    OTHER_MESSAGES,
    captured_output,
    summary,
    terminal_stream,
)
from comparators.timing import attempt_run

LIBC = ctypes.CDLL(None)


def test_c_level_writes_to_both_descriptors_go_into_the_record(capfd):
    with captured_output() as output:
        LIBC.write(2, b"C write on fd 2\n", 16)
        LIBC.printf(b"C printf on stdout\n")  # buffered by C's stdio until flushed
    terminal = capfd.readouterr()
    assert output.messages == {"C write on fd 2": 1, "C printf on stdout": 1}
    assert "C write" not in terminal.err + terminal.out
    assert "C printf" not in terminal.err + terminal.out


def test_python_output_and_every_warning_are_recorded_in_order(capfd):
    with captured_output() as output:
        print("python stdout")
        for _ in range(3):  # the same place each time: counted every time, not once
            warnings.warn("look out", RuntimeWarning, stacklevel=1)
        print("python stderr", file=sys.stderr)
        os.write(1, b"python stdout\n")
    terminal = capfd.readouterr()
    assert list(output.messages.items()) == [
        ("python stdout", 2),
        ("RuntimeWarning: look out", 3),
        ("python stderr", 1),
    ]
    assert terminal.out == "" and terminal.err == ""


def test_the_descriptors_are_restored_after_the_block_also_when_it_raises(capfd):
    with pytest.raises(ValueError), captured_output() as output:
        os.write(2, b"before the error\n")
        raise ValueError("boom")
    os.write(2, b"after the block\n")
    print("printed after")
    terminal = capfd.readouterr()
    assert output.messages == {"before the error": 1}
    assert terminal.err == "after the block\n" and terminal.out == "printed after\n"


def test_the_terminal_stream_writes_past_a_capture(capfd):
    """What a progress bar refreshed from a thread during a run writes stays on the terminal
    and out of the run's record."""
    terminal = terminal_stream()
    with captured_output() as output:
        terminal.write("progress 3/10\n")
        os.write(2, b"engine says\n")
    terminal.close()
    assert output.messages == {"engine says": 1}
    assert capfd.readouterr().out == "progress 3/10\n"


def test_messages_are_capped_in_number_and_length():
    with captured_output() as output:
        for k in range(MAX_MESSAGES + 5):
            os.write(2, f"message {k}\n".encode())
        os.write(2, b"x" * (MAX_MESSAGE_CHARS * 2) + b"\n")
    assert len(output.messages) == MAX_MESSAGES + 1
    assert output.messages[OTHER_MESSAGES] == 6
    assert "message 0" in output.messages and f"message {MAX_MESSAGES}" not in output.messages
    assert max(len(m) for m in output.messages) <= MAX_MESSAGE_CHARS
    assert summary(output.messages).startswith(
        f"{MAX_MESSAGES + 6} line(s) ({MAX_MESSAGES + 1} distinct)"
    )


class _Talkative:
    """The reference engine, saying something from C and from Python on the way; its
    integrator "fails" raises after saying it."""

    name = "talkative"
    integrators = ("euler", "fails")
    default_integrator = "euler"
    orders = {"euler": 1, "fails": 1}
    missing = None

    def run(self, scene, integrator, dt, duration):
        LIBC.write(2, b"solver: 3 iterations left\n", 26)
        warnings.warn("overflow in the model", RuntimeWarning, stacklevel=1)
        if integrator == "fails":
            raise RuntimeError("the model blew up")
        traj = registry.ENGINES["reference"].run(scene, "euler", dt, duration)
        return Trajectory(traj.table, dataclasses.replace(traj.meta, engine=self.name))


@pytest.fixture
def talkative(monkeypatch):
    monkeypatch.setitem(registry.ENGINES, "talkative", _Talkative())


SAID = {"solver: 3 iterations left": 1, "RuntimeWarning: overflow in the model": 1}


@pytest.mark.parametrize("suffix", ["parquet", "csv"])
def test_a_run_records_what_its_engine_said_through_the_cache(talkative, capfd, tmp_path, suffix):
    traj = run(CATALOG["free_spin_cube"], "talkative", duration=0.1)
    assert traj.meta.messages == SAID
    assert Trajectory.read(traj.write(tmp_path / f"t.{suffix}")).meta.messages == SAID
    terminal = capfd.readouterr()
    assert "iterations left" not in terminal.err + terminal.out
    assert "overflow" not in terminal.err + terminal.out


def test_a_failed_run_keeps_what_its_engine_said_in_its_reason(talkative, capfd):
    traj, reason = attempt_run(CATALOG["free_spin_cube"], "talkative", "fails", 0.01, 0.1)
    assert traj is None
    assert reason.startswith("RuntimeError: the model blew up; engine output: 2 line(s)")
    assert "first: solver: 3 iterations left" in reason
    assert "iterations left" not in capfd.readouterr().err


def test_a_mujoco_divergence_is_recorded_and_writes_no_log_in_the_cwd(tmp_path, monkeypatch):
    pytest.importorskip("mujoco")
    monkeypatch.chdir(tmp_path)
    traj = run(CATALOG["high_spin"], "mujoco", "Euler")  # diverges at the case's dt
    [message] = traj.meta.messages
    assert "Nan, Inf or huge value in QACC" in message
    assert list(tmp_path.iterdir()) == []  # no MUJOCO_LOG.TXT
