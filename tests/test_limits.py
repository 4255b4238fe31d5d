"""Limits on a run's size (`comparators.limits`): refused before any engine allocates, one line
naming the quantity, the limit and the option that raises it; raised, the run goes ahead."""

import dataclasses

import pytest

from cases import CATALOG, InputError
from comparators import run
from comparators.limits import MAX_STEPS, RECORDED_ENV, STEPS_ENV, check_run, current_limits
from reports.cli import main

CUBE = CATALOG["dropped_cube"]
SPIN = CATALOG["free_spin_cube"]


@pytest.fixture(autouse=True)
def default_limits(monkeypatch):
    monkeypatch.delenv(STEPS_ENV, raising=False)
    monkeypatch.delenv(RECORDED_ENV, raising=False)


@pytest.mark.parametrize("dt", [1e-300, 5e-324, CUBE.duration / (MAX_STEPS + 2)])
def test_too_many_steps_is_refused_without_overflow(dt):
    with pytest.raises(InputError, match=r"steps, over the limit of 1e\+08.*--max-steps"):
        check_run(CUBE, dt, CUBE.duration)


def test_the_step_limit_is_inclusive():
    check_run(SPIN, SPIN.duration / MAX_STEPS, SPIN.duration)  # exactly MAX_STEPS: allowed


def test_recorded_positions_are_samples_times_particles(monkeypatch):
    # 1,000 steps sampled every step: 1,001 samples (+1 for a last partial stride) x 8 particles
    monkeypatch.setenv(RECORDED_ENV, str(8 * 1002))
    check_run(CUBE, CUBE.dt, 1000 * CUBE.dt)
    monkeypatch.setenv(RECORDED_ENV, str(8 * 1002 - 1))
    with pytest.raises(InputError, match=r"x 8 particles .* raise it with --max-recorded"):
        check_run(CUBE, CUBE.dt, 1000 * CUBE.dt)


def test_a_sparse_sample_interval_records_less():
    sparse = dataclasses.replace(CUBE, sample_interval=1e100)
    assert sparse.sample_stride(1e-300) == 2**62  # clipped, no OverflowError
    check_run(sparse, CUBE.dt, 1e5)  # 1e8 steps, 2 samples: within both limits


def test_the_engine_entry_point_checks_before_it_allocates(monkeypatch):
    monkeypatch.setenv(STEPS_ENV, "10")
    with pytest.raises(InputError, match="11 steps, over the limit of 10"):
        run(SPIN, "reference", dt=SPIN.dt, duration=11 * SPIN.dt)


def test_a_bad_limit_in_the_environment_is_named(monkeypatch):
    monkeypatch.setenv(STEPS_ENV, "many")
    with pytest.raises(InputError, match=r"--max-steps \(RIGIDBENCH_MAX_STEPS\).*'many'"):
        current_limits()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "dropped_cube", "--duration", "1e6"], "raise it with --max-recorded"),
        (["run", "dropped_cube", "--dt", "1e-90"], "raise it with --max-steps"),
        (["bench", "--cases", "slide", "--dt", "1e-12"], "raise it with --max-steps"),
        (["animate", "slide", "--dt", "1e-12", "--out", "a.gif"], "raise it with --max-steps"),
        (["report", "--cases", "slide", "--max-steps", "2"], "over the limit of 2"),
    ],
)
def test_the_commands_refuse_before_any_run_and_write_nothing(args, message, tmp_path,
                                                              monkeypatch, capsys):  # fmt: skip
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and message in lines[0]
    assert list(tmp_path.iterdir()) == []


def test_raised_limits_reach_the_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "free_spin_cube", "--duration", "0.05", "--max-steps", "4"]) == 2
    assert main(["run", "free_spin_cube", "--duration", "0.05", "--max-steps", "5"]) == 0
    assert "verdict" in capsys.readouterr().out
