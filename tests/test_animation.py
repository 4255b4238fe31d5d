"""Animations of the motion: where particles are drawn (`particle_tracks`), the seed's recorded
particles through the results cache, the `animate` command and its GIF, and the report's."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_cli import rigidbench
from test_report import build_result

from cases import CATALOG
from comparators import run
from comparators.cache import ResultsCache
from comparators.reference import model_from_scene
from comparators.run_data import RunData, particle_tracks
from reference_sim.model import seed_initial_state
from reference_sim.seed import seed_step
from reports import animation
from reports.camera import scene_extent
from reports.figures import ANIMATED_CASES, animated_cases, animated_runs
from reports.html_page import missing_references
from reports.report import write_report

ROOT = Path(__file__).resolve().parents[1]
# A rigid run keeps every inter-particle distance to rounding: the rotation of a unit quaternion
# is orthogonal to ~1e-15 and seed_cube's coordinates are ~10 m, so 1e-12 relative leaves a
# hundredfold margin over rounding and is ten orders below the seed's deformation.
RIGID_DISTANCE_RTOL = 1e-12
# The seed's cube ends with every particle on the floor (to 1e-12 m, tests/test_seed.py); a
# rigid unit cube keeps at least 1 m of height however it rests. A twentieth of its starting
# height tells a flattened cube from any rigid one.
FLATTENED_FRACTION = 0.05
# At t = 0 the seed's best-fit rotation is the identity to rounding of an SVD of metre-scale
# offsets (~1e-15), so its pose places the particles where it recorded them to 1e-12 m.
PLACEMENT_ATOL = 1e-12
# The tumbling box's intermediate axis has flipped when it points within 25 degrees of where it
# pointed at t = 0, reversed (cos 25 deg = 0.906): the exact flip reverses it fully (cos = -1).
FLIPPED_COS = -0.9


@pytest.fixture(scope="module")
def seed_cube_seed():
    return run(CATALOG["seed_cube"], "reference", "seed")


@pytest.fixture(scope="module")
def seed_cube_rigid():
    return run(CATALOG["seed_cube"], "reference", "splitting")


def _heights(tracks, scene) -> np.ndarray:
    """(S,) extent of the scene's particles along gravity at each sample (m)."""
    up = -np.asarray(scene.gravity) / np.linalg.norm(scene.gravity)
    heights = np.concatenate(tracks, axis=1) @ up
    return heights.max(axis=1) - heights.min(axis=1)


def test_the_seeds_cube_flattens(seed_cube_seed):
    scene = CATALOG["seed_cube"]
    extent = _heights(particle_tracks(seed_cube_seed, scene), scene)
    assert extent[0] == pytest.approx(1.0)  # a unit cube, face down
    assert extent[-1] < FLATTENED_FRACTION * extent[0], (
        f"seed_cube seed: particles span {extent[-1]:.3g} m along gravity at the end, "
        f"{extent[0]:.3g} m at the start: not flattened"
    )


def test_a_rigid_cube_keeps_its_shape(seed_cube_rigid):
    scene = CATALOG["seed_cube"]
    (tracks,) = particle_tracks(seed_cube_rigid, scene)
    distances = np.linalg.norm(tracks[:, :, None] - tracks[:, None, :], axis=-1)
    pairs = ~np.eye(tracks.shape[1], dtype=bool)
    change = np.abs(distances[:, pairs] / distances[0, pairs] - 1)
    assert change.max() < RIGID_DISTANCE_RTOL, (
        f"seed_cube splitting: an inter-particle distance changed by {change.max():.3g} "
        f"(relative) at t = {seed_cube_rigid.table['t'].iloc[change.max(axis=1).argmax()]} s"
    )
    assert _heights([tracks], scene)[-1] > 1 - RIGID_DISTANCE_RTOL


def test_the_seeds_recorded_particles_are_its_particles(seed_cube_seed):
    """At t = 0 where the pose places them; at the end where stepping the seed directly
    (`seed_step`, the compiled blog step) leaves them, bit for bit."""
    scene = CATALOG["seed_cube"]
    recorded = seed_cube_seed.particles["cube"]
    placed = RunData(seed_cube_seed, scene).particles(0)
    np.testing.assert_allclose(recorded[0], placed[0], rtol=0, atol=PLACEMENT_ATOL)
    np.testing.assert_array_equal(recorded[0], scene.bodies[0].positions)
    body = scene.bodies[0]
    model = model_from_scene(scene)
    state = seed_initial_state(model, body.positions, [body.velocity], [body.angular_velocity])
    pos, vel, cm, v, omega = (a.copy() for a in state)
    for _ in range(seed_cube_seed.meta.steps):
        seed_step(model, pos, vel, cm, v, omega, scene.dt)
    np.testing.assert_array_equal(recorded[-1], pos)


def test_rigid_runs_record_no_particles(seed_cube_rigid):
    assert seed_cube_rigid.particles is None


def test_particles_survive_the_results_cache(seed_cube_seed, seed_cube_rigid, tmp_path):
    cache = ResultsCache(tmp_path)
    cache.put("seed", seed_cube_seed)
    cache.put("rigid", seed_cube_rigid)
    back = cache.get("seed")
    assert back.particles.keys() == seed_cube_seed.particles.keys()
    np.testing.assert_array_equal(back.particles["cube"], seed_cube_seed.particles["cube"])
    assert back.table.equals(seed_cube_seed.table)
    assert cache.get("rigid").particles is None
    assert cache.get("rigid").table.equals(seed_cube_rigid.table)


def test_particles_of_several_bodies_survive_parquet(tmp_path):
    """cube_rain_8's eight bodies: each body's particles come back as its own."""
    scene = dataclasses.replace(CATALOG["cube_rain_8"], duration=0.2)
    traj = run(scene, "reference", "seed")
    back = type(traj).read(traj.write(tmp_path / "rain.parquet"))
    assert list(back.particles) == [b.name for b in scene.bodies]
    for name, positions in traj.particles.items():
        np.testing.assert_array_equal(back.particles[name], positions)


@pytest.mark.parametrize("integrator", ["exact", "splitting"])
def test_the_tumbling_box_flips(integrator):
    """Its intermediate axis, read from the drawn particles (the mean of the lighter ones, on its
    positive side, from the mean of the others), turns to point backwards during the run."""
    scene = CATALOG["tumbling_box"]
    (tracks,) = particle_tracks(run(scene, "reference", integrator), scene)
    marked = animation.marked_particles(scene.bodies[0])
    axis = tracks[:, marked].mean(axis=1) - tracks[:, ~marked].mean(axis=1)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    cosine = axis @ axis[0]
    assert cosine.min() < FLIPPED_COS, (
        f"tumbling_box {integrator}: the intermediate axis came no closer to reversed than "
        f"cos = {cosine.min():.3f}"
    )


def test_marked_particles_are_one_side_of_the_intermediate_axis():
    box = CATALOG["tumbling_box"].bodies[0]  # 1 x 2 x 3: y is the intermediate axis
    offsets = box.positions - box.com
    np.testing.assert_array_equal(animation.marked_particles(box), offsets[:, 1] > 0)
    cube = CATALOG["free_spin_cube"].bodies[0]  # equal moments, spinning about x: y
    np.testing.assert_array_equal(
        animation.marked_particles(cube), (cube.positions - cube.com)[:, 1] > 0
    )


def test_bonds_of_a_box_are_its_edges():
    corners = CATALOG["tumbling_box"].bodies[0].positions
    links = animation.bonds(corners)
    lengths = sorted(np.linalg.norm(corners[i] - corners[j]) for i, j in links)
    assert lengths == pytest.approx([1.0] * 4 + [2.0] * 4 + [3.0] * 4)


# ---- the GIF ---------------------------------------------------------------------------------


def _frames(path: Path) -> list[np.ndarray]:
    with Image.open(path) as gif:
        out = []
        for k in range(gif.n_frames):
            gif.seek(k)
            out.append(np.asarray(gif.convert("RGB"), dtype=int))
        return out


def _cells_with_body(frame: np.ndarray, columns: int, rows: int) -> list[bool]:
    """Per grid cell (row by row), whether it shows a sphere of the first body's colour."""
    colour = np.array(animation.BODY_COLOURS[0])
    height, width = frame.shape[0] - animation.HEADER_PX, frame.shape[1]
    cells = []
    for row in range(rows):
        for column in range(columns):
            top = animation.HEADER_PX + row * height // rows
            cell = frame[top : top + height // rows, column * width // columns :][
                :, : width // columns
            ]
            near = np.abs(cell - colour).sum(axis=-1) < 30
            cells.append(bool(near.sum() > 20))
    return cells


def test_animate_writes_one_panel_per_run_and_one_frame_per_sample(tmp_path, monkeypatch):
    integrators = ["splitting", "exact", "euler", "rk4"]
    out = tmp_path / "box.gif"
    proc = rigidbench(
        "animate", "tumbling_box", "--engines", "reference", "--integrator", *integrators,
        "--duration", "1", "--out", str(out), "--cache", str(tmp_path / "cache"),
        cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert f"wrote {out}" in proc.stdout
    frames = _frames(out)
    assert len(frames) == 11  # samples every 0.1 s over 1 s, both ends
    # four panels: three in the first row, one in the second, two empty cells
    assert _cells_with_body(frames[0], 3, 2) == [True, True, True, True, False, False]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["box.gif", "cache"]
    stored = {p: p.stat().st_mtime_ns for p in (tmp_path / "cache").iterdir()}
    assert len(stored) == len(integrators)
    # the same runs where numba's cache lacks the compiled code: taken from the results cache
    # before anything is compiled, so nothing is
    numba_cache = tmp_path / "numba"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(numba_cache))
    again = rigidbench(
        "animate", "tumbling_box", "--engines", "reference", "--integrator", *integrators,
        "--duration", "1", "--out", str(tmp_path / "again.gif"), "--cache", str(tmp_path / "cache"),
        cwd=tmp_path,
    )  # fmt: skip
    assert again.returncode == 0, again.stderr
    assert "running" not in again.stdout  # nothing to run, and the output says so
    # the runs came from the cache: no entry added or rewritten
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "cache").iterdir()} == stored
    assert not [p for p in numba_cache.rglob("*") if p.is_file()]
    assert _frames(tmp_path / "again.gif")[-1].tolist() == frames[-1].tolist()


def test_frames_follow_the_samples_and_the_time_axis():
    scene = CATALOG["seed_cube"]
    panel = animation.Panel("x", [np.zeros((1001, 8, 3))], np.arange(1001) * 0.1)
    times = animation.frame_times([panel], scene.duration)
    assert len(times) <= animation.MAX_FRAMES
    assert times[0] == 0.0 and times[-1] == pytest.approx(100.0)
    steps = np.diff(times)[:-1]
    assert np.allclose(steps, steps[0]) and steps[0] == pytest.approx(1.3)  # 13 samples apart


def test_a_diverged_run_is_drawn_up_to_its_last_finite_sample(tmp_path):
    scene = dataclasses.replace(CATALOG["tumbling_box"], duration=1.0)
    good = run(scene, "reference", "splitting")
    table = good.table.copy()
    table.loc[table["t"] >= 0.5 - 1e-9, ["x", "qw"]] = np.nan
    broken = dataclasses.replace(good, table=table)
    panel = animation.panel_of("broken", broken, scene)
    assert panel.diverged_at == pytest.approx(0.5)
    path = animation.animate(
        scene,
        [("good", good), ("broken", broken), ("failed", "RuntimeError: no")],
        tmp_path / "d.gif",
    )
    frames = _frames(path)
    assert len(frames) == 11
    # the broken panel shows its body throughout, frozen from t = 0.5 s on
    assert _cells_with_body(frames[-1], 3, 1) == [True, True, False]
    red = np.array(animation.DIVERGED)
    width = frames[0].shape[1] // 3

    def marked(frame):
        cell = frame[:, width : 2 * width]
        return (np.abs(cell - red).sum(axis=-1) < 60).sum() > 10

    assert not marked(frames[4]) and marked(frames[5]) and marked(frames[-1])


def test_a_run_that_flew_off_does_not_set_the_camera(tmp_path):
    scene = dataclasses.replace(CATALOG["dropped_cube"], duration=1.0)
    good = run(scene, "reference", "splitting")
    table = good.table.copy()
    table.loc[table["t"] > 0.5, "z"] = 1e200  # finite, and far beyond any panel
    flown = dataclasses.replace(good, table=table)
    runs = [particle_tracks(t, scene) for t in (good, flown)]
    np.testing.assert_array_equal(scene_extent(scene, runs), scene_extent(scene, runs[:1]))
    path = animation.animate(scene, [("flown", flown)], tmp_path / "alone.gif")  # no overflow
    assert len(_frames(path)) == 51


BAD_INPUT = [
    (["animate", "no_such_case", "--out", "a.gif"], "unknown case 'no_such_case'"),
    (["animate", "tumbling_box", "--engines", "warp", "--out", "a.gif"], "unknown engine 'warp'"),
    (
        [
            "animate",
            "tumbling_box",
            "--engines",
            "mujoco",
            "--integrator",
            "seed",
            "--out",
            "a.gif",
        ],
        "unknown integrator 'seed' for engine 'mujoco'",
    ),
    (["animate", "tumbling_box", "--out", "a.mp4"], "expected a file name ending in .gif"),
    (["animate", "tumbling_box", "--out", "missing/a.gif"], "directory 'missing' missing"),
    (["animate", "tumbling_box", "--dt", "nan", "--out", "a.gif"], "expected a finite number > 0"),
    (
        ["animate", "tumbling_box", "--dt", "20", "--out", "a.gif"],
        "dt 20 is longer than duration 10",
    ),
    (["animate", "tumbling_box"], "the following arguments are required: --out"),
]


@pytest.mark.parametrize(("args", "message"), BAD_INPUT, ids=[m for _, m in BAD_INPUT])
def test_bad_input_exits_2_and_writes_nothing(args, message, tmp_path):
    proc = rigidbench(*args, "--cache", str(tmp_path / "cache"), cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert message in proc.stderr
    assert proc.stdout == ""
    assert list(tmp_path.iterdir()) == []


# ---- the report ------------------------------------------------------------------------------


def test_the_report_animates_each_core_case(tmp_path):
    """The core cases, shortened to 1 s, at their default dt: each gets its animation (the
    seed's cube beside the reference's default integrator on seed_cube only) in a Motion
    subsection of its section, and the page finds every file it shows."""
    scenes = [dataclasses.replace(CATALOG[name], duration=1.0) for name in ANIMATED_CASES]
    scenes.append(dataclasses.replace(CATALOG["resting_cube"], duration=1.0))  # not animated
    assert {s.dt for s in scenes} == {0.01}
    result = build_result(scenes, [("reference", "splitting"), ("reference", "seed")], [0.01])
    labels = [label for label, _ in animated_runs(result, "seed_cube")]
    assert labels == ["reference/splitting", "reference/seed"]
    assert [label for label, _ in animated_runs(result, "dropped_cube")] == ["reference/splitting"]
    write_report(result, tmp_path, "pytest tests/test_animation.py")
    text = (tmp_path / "report.md").read_text()
    sections = text.split("## Case `")[1:]
    for section in sections:
        case = section.split("`")[0]
        animated = case in ANIMATED_CASES
        assert ("### Motion" in section) == animated, case
        assert (f"figures/{case}_motion.gif" in section) == animated, case
    assert len(sections) == len(scenes)
    with Image.open(tmp_path / "figures" / "seed_cube_motion.gif") as gif:
        assert gif.n_frames == 11  # samples every 0.1 s over 1 s
    assert missing_references(tmp_path / "index.html") == []


def test_a_full_report_animates_the_hard_cases_too():
    scenes = {name: CATALOG[name] for name in ("tumbling_box", "high_spin", "free_spin_cube")}
    assert animated_cases(scenes, full=False) == ANIMATED_CASES
    assert animated_cases(scenes, full=True) == (*ANIMATED_CASES, "high_spin")
