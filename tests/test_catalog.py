"""The catalog and the builders: mass properties and what each case states."""

import numpy as np
import pytest

from cases import CATALOG
from cases.builders import box_corners, box_lattice, box_walls, seed_cube


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
    assert len(seed_cube()) == 8
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
