"""The catalog and the builders: mass properties and what each case states."""

import subprocess
import sys

import numpy as np
import pytest

from cases import CATALOG
from cases.builders import (
    box_corners,
    box_lattice,
    box_walls,
    cube_above_floor,
    incline_plane,
    rotated,
    rotation_y,
    seed_cube_particles,
    stacked,
)
from comparators.metrics import REST_WINDOW
from rigidmath.inertia import principal_frame


@pytest.mark.parametrize(
    ("case", "inertia"),
    [
        ("seed_cube", (4.0, 4.0, 4.0)),
        ("free_spin_cube", (4.0, 4.0, 4.0)),
        ("dropped_cube", (4.0, 4.0, 4.0)),
        ("tumbling_box", (26.0, 20.0, 10.0)),
    ],
)
def test_catalog_inertia(case, inertia):
    body = CATALOG[case].bodies[0]
    np.testing.assert_allclose(body.inertia, np.diag(inertia), rtol=0, atol=1e-12)
    assert body.mass == 8.0


@pytest.mark.parametrize("case", sorted(CATALOG))
def test_every_case_describes_itself(case):
    scene = CATALOG[case]
    assert scene.description and scene.tags
    assert scene.modelled()


def test_seed_cube_is_the_blogs_scene():
    scene = CATALOG["seed_cube"]
    body = scene.bodies[0]
    np.testing.assert_array_equal(body.positions.min(axis=0), (3, 3, 7))
    np.testing.assert_array_equal(body.positions.max(axis=0), (4, 4, 8))
    assert body.particle_radius == 0.2 and body.velocity == (0, 0, -2)
    assert body.angular_velocity == (2, 0, 0) and scene.gravity == (0, 0, -10)
    assert (scene.dt, scene.duration, scene.contact.restitution) == (0.01, 100.0, 0.0)
    assert scene.planes == box_walls((0, 0, 0), (10, 10, 10))


def test_dropped_cube_starts_two_metres_up():
    body = CATALOG["dropped_cube"].bodies[0]
    assert body.positions[:, 2].min() == 2.0
    assert CATALOG["dropped_cube"].expected.rest_com_height == 0.7


def test_builders():
    assert len(seed_cube_particles()) == 8
    corners = np.array(box_corners((1.0, 2.0, 3.0), center=(1.0, 1.0, 1.0)))
    np.testing.assert_array_equal(np.ptp(corners[:, :3], axis=0), (1, 2, 3))
    np.testing.assert_array_equal(corners[:, :3].mean(axis=0), (1, 1, 1))
    lattice = np.array(box_lattice((2.0, 2.0, 2.0), (3, 4, 1), mass=0.5))
    assert lattice.shape == (12, 4) and np.all(lattice[:, 3] == 0.5)
    assert np.all(lattice[:, 2] == 0.0)  # one layer sits on the centre plane
    walls = box_walls()
    assert len(walls) == 6
    for wall in walls:  # every normal points into the box
        inside = np.dot(np.full(3, 5.0) - wall.point, wall.unit_normal)
        assert inside == 5.0


# --- the hard cases ---------------------------------------------------------------------------

# Positions at t = 0 are sums, products and (incline) one rotation of numbers of order 1: a gap
# that should be 0 comes out within a few 1e-16 m. 1e-12 leaves room, yet is far below anything
# an engine could notice (its own contact tolerances are 1e-10 m and up).
GAP_TOL = 1e-12
# The catalog and these tests evaluate the same closed forms by different routes (powers against
# products, an apex time summed bounce by bounce against the geometric series): rounding, ~1e-16.
CLOSED_FORM_RTOL = 1e-12
# A planar lattice has C = A + B exactly; the eigen-solver and the COM subtraction round it.
PLANAR_RTOL = 1e-12
MIN_INERTIA_RATIO = 100  # the brief for thin_rod and flat_plate: a stiff omega = I^-1 L
OFF_AXIS_FRACTION = 0.2  # a tumble is "off-axis" when omega has this share on every axis
HARD = sorted(name for name, scene in CATALOG.items() if "hard" in scene.tags)
NEW_CASES = {
    "stability": [
        "tumbling_box_long",
        "high_spin",
        "thin_rod",
        "flat_plate",
        "resting_cube",
        "fast_impact",
        "cube_stack",
        "cube_collision",
    ],
    "contact-closed-form": [
        "bounce",
        "bounce_e0.3",
        "bounce_e0.8",
        "slide",
        "slide_oblique",
        "spin_down",
        "incline",
        "incline_stick",
    ],
}
G = 10.0
CUBE_REST_HEIGHT = 0.7  # m: half the unit edge plus the particle radius 0.2


def plane_gaps(body, plane) -> np.ndarray:
    """Each particle's surface clearance above `plane` (negative: overlapping)."""
    return (body.positions - plane.point) @ plane.unit_normal - body.particle_radius


def pair_gaps(a, b) -> np.ndarray:
    """Surface clearance of every particle pair of bodies `a` and `b`."""
    distances = np.linalg.norm(a.positions[:, None, :] - b.positions[None, :, :], axis=-1)
    return distances - a.particle_radius - b.particle_radius


def test_hard_cases_are_all_registered():
    assert HARD == sorted(sum(NEW_CASES.values(), []))


@pytest.mark.parametrize(("group", "case"), [(g, c) for g, cs in NEW_CASES.items() for c in cs])
def test_hard_case_tags(group, case):
    scene = CATALOG[case]
    other = ({"stability", "contact-closed-form"} - {group}).pop()
    assert "hard" in scene.tags and group in scene.tags and other not in scene.tags
    assert "\n" not in scene.description
    assert scene.gravity in ((0, 0, 0), (0, 0, -10))
    assert ("gravity" in scene.tags) == scene.has_gravity
    assert ("contact" in scene.tags) == scene.has_contact
    assert ("multibody" in scene.tags) == (len(scene.bodies) > 1)
    assert ("free" in scene.tags) == ("exact" in scene.tags) == (not scene.has_contact)


@pytest.mark.parametrize("case", [c for c in HARD if CATALOG[c].has_contact])
def test_contact_outcomes_are_sampled_every_default_step(case):
    scene = CATALOG[case]
    expected = scene.dt if not case.startswith("incline") else 0.01  # a slope: a smooth motion
    assert scene.sample_interval == expected


def test_tumbling_box_long_is_tumbling_box_for_longer():
    short, long = CATALOG["tumbling_box"], CATALOG["tumbling_box_long"]
    assert (long.duration, long.sample_interval) == (100.0, 0.1)
    assert (long.bodies, long.dt, long.gravity) == (short.bodies, short.dt, short.gravity)


def test_high_spin():
    scene = CATALOG["high_spin"]
    body = scene.bodies[0]
    omega = np.asarray(body.angular_velocity)
    assert np.linalg.norm(omega) * scene.dt == pytest.approx(0.5, rel=CLOSED_FORM_RTOL)
    assert body.particles == box_corners((1.0, 2.0, 3.0))
    moments, axes = principal_frame(body.inertia)
    # mostly about the largest-inertia axis (a stable one), with an off-axis part
    cosine = abs(axes[:, -1] @ omega) / np.linalg.norm(omega)
    assert 0.99 < cosine < 1.0
    assert not scene.has_gravity and not scene.has_contact and scene.duration == 10.0


@pytest.mark.parametrize("case", ["thin_rod", "flat_plate"])
def test_stiff_tumblers(case):
    scene = CATALOG[case]
    body = scene.bodies[0]
    moments, _ = principal_frame(body.inertia)
    ratio = moments[-1] / moments[0]
    assert ratio >= MIN_INERTIA_RATIO
    assert f"principal inertia ratio {ratio:.4g}" in scene.description
    # axis-aligned (so world axes are principal) and omega well away from every one of them
    off_diagonal = body.inertia - np.diag(np.diag(body.inertia))
    np.testing.assert_allclose(off_diagonal, 0, atol=GAP_TOL)
    omega = np.abs(body.angular_velocity)
    assert np.all(omega >= OFF_AXIS_FRACTION * np.linalg.norm(omega))
    assert not scene.has_gravity and not scene.has_contact and scene.duration == 10.0


def test_flat_plate_is_planar():
    body = CATALOG["flat_plate"].bodies[0]
    assert np.ptp(body.positions[:, 2]) == 0.0  # every particle in one plane
    moments, _ = principal_frame(body.inertia)
    assert moments[2] == pytest.approx(moments[0] + moments[1], rel=PLANAR_RTOL)


@pytest.mark.parametrize(
    ("case", "clearance"),
    [
        ("resting_cube", 0.0),
        ("slide", 0.0),
        ("slide_oblique", 0.0),
        ("spin_down", 0.0),
        ("incline", 0.0),
        ("incline_stick", 0.0),
        ("cube_stack", 0.0),
        ("fast_impact", 0.5),
        ("bounce", 1.0),
        ("bounce_e0.3", 1.0),
        ("bounce_e0.8", 1.0),
    ],
)
def test_cube_starts_flat_at_its_clearance(case, clearance):
    scene = CATALOG[case]
    (plane,) = scene.planes
    gaps = plane_gaps(scene.bodies[0], plane)
    assert gaps.min() == pytest.approx(clearance, abs=GAP_TOL)
    # a whole face, 4 particles, at the lowest clearance: the cube lies flat
    assert np.sum(np.abs(gaps - clearance) <= GAP_TOL) == 4
    assert scene.bodies[0].com @ plane.unit_normal - clearance == pytest.approx(
        CUBE_REST_HEIGHT, abs=GAP_TOL
    )


def test_cube_stack_touches_exactly():
    scene = CATALOG["cube_stack"]
    assert len(scene.bodies) == 5
    heights = [body.com[2] for body in scene.bodies]
    np.testing.assert_allclose(heights, [0.7, 2.1, 3.5, 4.9, 6.3], rtol=0, atol=GAP_TOL)
    for below, above in zip(scene.bodies, scene.bodies[1:], strict=False):
        gaps = pair_gaps(below, above)
        assert gaps.min() == pytest.approx(0.0, abs=GAP_TOL)
        assert np.sum(np.abs(gaps) <= GAP_TOL) == 4  # face on face: 4 particle pairs touch
    for i, a in enumerate(scene.bodies):  # nowhere overlapping
        for b in scene.bodies[i + 1 :]:
            assert pair_gaps(a, b).min() >= -GAP_TOL
    assert all(b.velocity == (0, 0, 0) and b.angular_velocity == (0, 0, 0) for b in scene.bodies)


def test_cube_collision_hits_off_centre():
    scene = CATALOG["cube_collision"]
    target, projectile = scene.bodies
    assert not scene.planes and not scene.has_gravity and scene.contact.restitution == 0.5
    assert target.velocity == (0, 0, 0) and projectile.velocity == (2.0, 0, 0)
    assert pair_gaps(target, projectile).min() > 0  # apart at t = 0
    # Along straight lines, a particle pair meets when its distance across the motion (y, z) is
    # under two radii and the projectile's particle is behind the target's.
    offset = target.positions[:, None, :] - projectile.positions[None, :, :]
    across = np.linalg.norm(offset[..., 1:], axis=-1)
    meets = (across < 2 * target.particle_radius) & (offset[..., 0] > 0)
    assert 0 < meets.sum() < len(target.particles)  # some pairs, not a head-on face
    centres = target.com - projectile.com
    assert np.linalg.norm(centres[1:]) > 0.5  # off-centre: the push has a lever arm


def apex_heights(h0, e, duration):
    """Apex clearances of a drop from rest: summed bounce by bounce from the impact speeds."""
    t_fall = np.sqrt(2 * h0 / G)
    out, t = [], t_fall
    for k in range(1, 4):
        speed = G * t_fall * e**k  # the k-th rebound speed
        height = speed**2 / (2 * G)
        if t + speed / G <= duration and height >= 1e-3:
            out.append(height)
        t += 2 * speed / G
    return out


@pytest.mark.parametrize(
    ("case", "e"), [("bounce", 0.5), ("bounce_e0.3", 0.3), ("bounce_e0.8", 0.8)]
)
def test_bounce_expectations(case, e):
    scene = CATALOG[case]
    body, (plane,) = scene.bodies[0], scene.planes
    h0 = plane_gaps(body, plane).min()
    assert (scene.contact.restitution, scene.contact.friction) == (e, 0.0)
    assert body.velocity == (0, 0, 0) and body.angular_velocity == (0, 0, 0)
    assert (scene.dt, scene.sample_interval) == (0.001, 0.001)
    expected = scene.expected
    assert expected.rebound_ratio == e and expected.rest_com_height == CUBE_REST_HEIGHT
    np.testing.assert_allclose(
        expected.apex_heights, apex_heights(h0, e, scene.duration), rtol=CLOSED_FORM_RTOL
    )
    assert len(expected.apex_heights) == (2 if e == 0.3 else 3)  # 0.3^6 m is under 1 mm
    # Long enough to settle: the bounces end t_fall (1 + e) / (1 - e) after the drop.
    rest_time = np.sqrt(2 * h0 / G) * (1 + e) / (1 - e)
    assert scene.duration >= max(3.0, rest_time + REST_WINDOW)


@pytest.mark.parametrize(
    ("case", "degrees", "footprint"), [("slide", 0.0, (1, 1)), ("slide_oblique", 30.0, (2, 1))]
)
def test_slide_expectations(case, degrees, footprint):
    scene = CATALOG[case]
    body = scene.bodies[0]
    v, mu = np.asarray(body.velocity), scene.contact.friction
    v0 = np.linalg.norm(v)
    assert (v0, v[2], mu, scene.contact.restitution) == pytest.approx((3.0, 0, 0.5, 0.0))
    # launched `degrees` off the x axis, which the body's faces are aligned with: on the oblique
    # box also off its long axis, and so off its principal axes
    assert np.degrees(np.arctan2(v[1], v[0])) == pytest.approx(degrees, rel=CLOSED_FORM_RTOL)
    spans = np.ptp(body.positions, axis=0)
    assert spans == pytest.approx([*footprint, 1.0])  # as high as the seed's cube
    assert body.angular_velocity == (0, 0, 0)
    # uniform deceleration mu g: v0 = mu g t, d = v0 t / 2
    t_stop = v0 / (mu * G)
    assert scene.expected.stopping_time == pytest.approx(t_stop, rel=CLOSED_FORM_RTOL)
    assert scene.expected.stopping_distance == pytest.approx(v0 * t_stop / 2, rel=CLOSED_FORM_RTOL)
    assert scene.expected.rest_com_height == CUBE_REST_HEIGHT
    assert scene.duration > t_stop + REST_WINDOW


def test_spin_down_expectations():
    """The seed's cube (8 unit masses at the corners of a unit cube) spun at 5 rad/s: I_zz is
    8 x 0.5 kg m^2, its bottom corners are sqrt(0.5) m off the axis, and friction's torque
    mu m g r decelerates it uniformly."""
    scene = CATALOG["spin_down"]
    body = scene.bodies[0]
    assert body.angular_velocity == (0, 0, 5.0) and body.velocity == (0, 0, 0)
    assert body.inertia[2, 2] == pytest.approx(4.0, rel=CLOSED_FORM_RTOL)
    bottom = body.positions[:4] - body.com  # the cube's first four particles: its bottom face
    assert np.hypot(bottom[:, 0], bottom[:, 1]) == pytest.approx([np.sqrt(0.5)] * 4)
    a = 0.5 * 8.0 * G * np.sqrt(0.5) / 4.0  # rad/s^2
    assert scene.expected.spin_time == pytest.approx(5.0 / a, rel=CLOSED_FORM_RTOL)
    assert scene.expected.spin_angle == pytest.approx(25.0 / (2 * a), rel=CLOSED_FORM_RTOL)
    assert scene.expected.rest_com_height == CUBE_REST_HEIGHT
    assert scene.duration > scene.expected.spin_time + REST_WINDOW


@pytest.mark.parametrize(("case", "degrees"), [("incline", 35.0), ("incline_stick", 20.0)])
def test_incline_expectations(case, degrees):
    scene = CATALOG[case]
    (plane,) = scene.planes
    n = plane.unit_normal
    theta = np.arctan2(n[0], n[2])
    assert np.degrees(theta) == pytest.approx(degrees, rel=CLOSED_FORM_RTOL) and n[1] == 0
    np.testing.assert_array_equal(plane.point, (0, 0, 0))
    body, mu = scene.bodies[0], scene.contact.friction
    assert body.velocity == (0, 0, 0) and body.angular_velocity == (0, 0, 0)
    # Along the slope: gravity's component g sin theta against at most mu g cos theta.
    downhill = np.array([np.cos(theta), 0.0, -np.sin(theta)])
    drive = -np.asarray(scene.gravity) @ -downhill  # g sin theta
    grip = mu * -np.asarray(scene.gravity) @ n  # mu g cos theta
    assert scene.expected.slope_acceleration == pytest.approx(
        max(drive - grip, 0.0), rel=CLOSED_FORM_RTOL, abs=0.0
    )
    assert (scene.expected.slope_acceleration > 0) == (case == "incline")
    # the cube's edges follow the slope: its downhill edge is parallel to the plane
    rows = body.positions
    bottom = rows[np.abs(plane_gaps(body, plane)) <= GAP_TOL]
    spans = bottom - bottom[0]
    np.testing.assert_allclose(spans @ n, 0, atol=GAP_TOL)


def test_rotation_builders():
    theta = 0.3
    rotation = rotation_y(theta)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(rotation @ (0, 0, 1), incline_plane(theta).unit_normal, atol=1e-15)
    rows = cube_above_floor(gap=0.25)
    turned = np.array(rotated(rows, rotation, about=(1.0, 2.0, 3.0)))
    pivot = np.array([1.0, 2.0, 3.0])
    original = np.array(rows)
    np.testing.assert_allclose(turned[:, 3], original[:, 3])
    np.testing.assert_allclose(  # distances to the pivot are kept
        np.linalg.norm(turned[:, :3] - pivot, axis=1),
        np.linalg.norm(original[:, :3] - pivot, axis=1),
        atol=1e-14,
    )
    assert original[:, 2].min() == pytest.approx(0.2 + 0.25)
    tower = stacked(rows, 3, 1.5)
    assert len(tower) == 3
    np.testing.assert_allclose(np.array(tower[2])[:, :3] - original[:, :3], [[0, 0, 3.0]] * 8)


def test_cases_stand_alone_without_any_engine():
    """Loading every case imports no engine: the scenes are engine-neutral (their rigid-body
    math lives in `rigidmath`)."""
    code = (
        "import sys, cases; cases.resolve_case('cube_rain_20'); "
        "print(sorted({m.split('.')[0] for m in sys.modules} "
        "& {'reference_sim', 'comparators', 'reports', 'numba', 'mujoco', 'pybullet'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
