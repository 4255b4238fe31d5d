"""The results cache keeps nothing wrong: a damaged, foreign or unstamped entry is discarded
with one warning and its run computed again; a report survives it with the same results."""

import dataclasses
import shutil
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq
import pytest
from test_cli import rigidbench

from cases import CATALOG
from comparators.cache import DISCARDED, CacheWarning, ResultsCache, run_key
from comparators.sweep import plan, run_sweep

SHORT = [dataclasses.replace(CATALOG["free_spin_cube"], duration=0.5)]
# the columns of results.csv that differ from one run of the same spec to the next: timings
TIMED = ["setup_s", "wall_s", "wall_min_s", "wall_max_s", "steps_per_s", "realtime_factor"]


class CountingExecutor:
    """Runs in this process and remembers which specs it ran."""

    name = "serial"

    def __init__(self):
        self.ran = []

    def map_unordered(self, fn, items):
        for item in items:
            self.ran.append(item)
            yield item, fn(item)


def key(spec) -> str:
    return run_key(spec.scene, spec.engine, spec.integrator, spec.dt, spec.repeats)


@pytest.fixture(scope="module")
def filled(tmp_path_factory):
    """A cache holding four reference runs (two integrators, two dt), and their specs."""
    root = tmp_path_factory.mktemp("filled")
    specs = plan(SHORT, ["reference"], repeats=1, dt_factors=(2.0, 1.0))
    specs = [s for s in specs if s.integrator in ("euler", "splitting")]
    result = run_sweep(specs, ResultsCache(root), CountingExecutor(), progress=False)
    assert result.computed == len(specs) == 4
    return root, specs


@pytest.fixture
def cache(filled, tmp_path):
    root, _ = filled
    shutil.copytree(root, tmp_path / "cache")
    return ResultsCache(tmp_path / "cache")


def truncate(path, other):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def garbage(path, other):
    path.write_bytes(b"\x00 not a parquet file \xff" * 100)


def foreign(path, other):
    shutil.copyfile(other, path)  # a valid entry, of another run


def tampered(path, other):
    """A readable file under the right key whose values changed: only the checksum tells."""
    arrow = pq.read_table(path)
    x = arrow.column("x").to_numpy().copy()
    x[len(x) // 2] += 1e-9
    arrow = arrow.set_column(arrow.column_names.index("x"), "x", [x])
    pq.write_table(arrow, path)


def unstamped(path, other):
    """As the previous rigidbench wrote it: no key, no checksum."""
    from comparators.trajectory import Trajectory

    Trajectory.read(path).write(path)


def flip_a_data_byte(path, other):
    """One byte inside the column chunk of x flipped, the first (from its end) after which the
    file still reads, with other values: only the checksum tells."""
    original = pq.read_table(path)
    chunk = pq.ParquetFile(path).metadata.row_group(0).column(original.column_names.index("x"))
    data = path.read_bytes()
    for offset in range(chunk.data_page_offset + chunk.total_compressed_size - 1, 0, -1):
        flipped = bytearray(data)
        flipped[offset] ^= 0x01
        path.write_bytes(bytes(flipped))
        try:
            if not pq.read_table(path).equals(original):
                return
        except OSError:
            pass
    raise AssertionError("no byte of x's chunk flips into a readable file")


DAMAGES = {
    truncate: "is unreadable",
    garbage: "is unreadable",
    foreign: "holds the run of another key",
    tampered: "fails its checksum",
    flip_a_data_byte: "fails its checksum",
    unstamped: "has no key or checksum",
}


@pytest.mark.parametrize("damage", list(DAMAGES), ids=lambda d: d.__name__)
def test_a_bad_entry_is_one_warning_then_a_miss(cache, filled, damage):
    _, specs = filled
    path, other = cache.path(key(specs[0])), cache.path(key(specs[1]))
    damage(path, other)
    with pytest.warns(CacheWarning) as caught:
        assert cache.get(key(specs[0])) is None
    warned = [str(w.message) for w in caught if issubclass(w.category, CacheWarning)]
    assert len(warned) == 1, warned
    assert path.as_posix() in warned[0] and "\n" not in warned[0]
    assert DAMAGES[damage] in warned[0]
    assert not path.exists() and (cache.root / DISCARDED / path.name).exists()
    assert cache.get(key(specs[1])) is not None  # the entry copied from is untouched


@pytest.mark.parametrize(
    "damage", [truncate, garbage, foreign, unstamped], ids=lambda d: d.__name__
)
def test_has_reads_the_stamp_from_the_footer(cache, filled, damage):
    """`has` (the gates' check) refuses what the footer shows; a tampered value is `get`'s."""
    _, specs = filled
    damage(cache.path(key(specs[0])), cache.path(key(specs[1])))
    with pytest.warns(CacheWarning):
        assert not cache.has(key(specs[0]))
    assert not cache.path(key(specs[0])).exists()
    assert cache.has(key(specs[1]))


def test_a_sweep_recomputes_exactly_the_bad_entries(cache, filled):
    root, specs = filled
    before = run_sweep(specs, ResultsCache(root), CountingExecutor(), progress=False)
    damaged = specs[:2]
    for spec, damage in zip(damaged, (truncate, foreign), strict=True):
        damage(cache.path(key(spec)), cache.path(key(specs[3])))
    executor = CountingExecutor()
    with pytest.warns(CacheWarning) as caught:
        after = run_sweep(specs, cache, executor, progress=False)
    assert len([w for w in caught if issubclass(w.category, CacheWarning)]) == 2
    assert sorted(executor.ran, key=specs.index) == damaged
    assert (after.computed, after.cached) == (2, 2)
    for k, traj in before.trajectories.items():
        pd.testing.assert_frame_equal(after.trajectories[k].table, traj.table)
    again = CountingExecutor()
    run_sweep(specs, cache, again, progress=False)  # the recomputed entries are good ones
    assert again.ran == []


def test_a_report_survives_a_corrupted_cache(tmp_path):
    out = tmp_path / "report"
    args = ("report", "--quick", "--cases", "free_spin_cube", "--engines", "reference", "mujoco",
            "--no-scaling", "--out", str(out))  # fmt: skip
    first = rigidbench(*args)
    assert first.returncode == 0, first.stderr
    results = pd.read_csv(out / "results.csv")
    entries = sorted((out / "cache").glob("*.parquet"))
    truncate(entries[0], None)
    foreign(entries[1], entries[2])
    second = rigidbench(*args)
    assert second.returncode == 0, second.stderr
    lines = second.stderr.strip().splitlines()
    assert len(lines) == 2, second.stderr
    assert all(line.startswith("rigidbench: warning: cache entry ") for line in lines)
    said = {entry.name: line for entry in entries[:2] for line in lines if entry.name in line}
    assert "unreadable" in said[entries[0].name] and "another key" in said[entries[1].name]
    assert "2 computed" in second.stdout
    again = pd.read_csv(out / "results.csv")
    pd.testing.assert_frame_equal(again.drop(columns=TIMED), results.drop(columns=TIMED))


def test_gates_recompute_the_bad_entries_and_count_them(tmp_path):
    """Gates ask `has` which runs are stored: a bad entry is computed in the first sweep and
    counted as computed, not as cached."""
    from gates.evaluate import evaluate
    from gates.spec import load_gates

    gate_file = Path(__file__).parent / "gates" / "mujoco.toml"
    gates, cache = load_gates([gate_file]), ResultsCache(tmp_path)
    first = evaluate(gates, cache, progress=False, executor=CountingExecutor())
    entries = sorted(tmp_path.glob("*.parquet"))
    truncate(entries[0], None)
    foreign(entries[1], entries[2])
    with pytest.warns(CacheWarning) as caught:
        again = evaluate(gates, cache, progress=False, executor=CountingExecutor())
    assert len([w for w in caught if issubclass(w.category, CacheWarning)]) == 2
    assert (again.attrs["computed"], again.attrs["cached"]) == (2, first.attrs["computed"] - 2)
    assert again["passed"].tolist() == first["passed"].tolist()
