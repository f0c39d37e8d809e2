"""A particle near two obstacles at once is kept out of both (design §3,
``contact_rows``): a box pushing the cloth into the table's corner, a wedge
whose face pushes it down into the table.

Behaviour and invariants: which rows get a second obstacle, the landing and
filters of a doubled row, the release of the obstacle that pulls, and whole
runs in which no particle enters either obstacle.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import scene_from_dict
from cloth_lod_ros.sim.contact.obstacles import Box, Plane
from cloth_lod_ros.sim.contact.contacts import ContactSet, find_contacts, penetrations
from cloth_lod_ros.sim.contact.contact_rows import TwoNormals
from cloth_lod_ros.sim.integrate.implicit_stage import _release

H = 1.0 / 60.0
THICKNESS = 0.004


def _table_and_wall():
    """The table z = 0 and a box whose face x = 0 faces −x."""
    table = Plane("table", 0.4, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    wall = Box("wall", 0.3, np.array([0.1, 0.0, 0.0]), np.array([0.1, 1.0, 0.2]),
               np.array([0.0, 0.0, 0.0, 1.0]))
    return [table, wall]


def test_a_particle_in_the_corner_is_constrained_against_both_obstacles():
    x = np.array([[-0.005, 0.0, 0.004],      # in the corner
                  [-0.2, 0.0, 0.004],        # on the table only
                  [-0.004, 0.0, 0.1]])       # against the wall only
    contacts = find_contacts(_table_and_wall(), x, THICKNESS)
    assert list(contacts.indices) == [0, 1, 2]
    assert list(contacts.doubled) == [True, False, False]
    pair = {tuple(contacts.normals[0]), tuple(contacts.second.normals[0])}
    assert pair == {(0.0, 0.0, 1.0), (-1.0, 0.0, 0.0)}
    # The second obstacle's distance is its own (φ − thickness), its friction its own.
    first_is_table = contacts.normals[0, 2] == 1.0
    assert contacts.second.friction[0] == (0.3 if first_is_table else 0.4)
    np.testing.assert_allclose(sorted([contacts.distance[0], contacts.second.distance[0]]),
                               [0.0, 0.001], atol=1e-12)
    assert not contacts.second.normals[1:].any()


def test_nearly_parallel_or_opposite_surfaces_give_no_second_normal():
    low = Plane("low", 0.4, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    tilted = Plane("tilted", 0.4, np.zeros(3), np.array([np.sin(0.1), 0.0, np.cos(0.1)]))
    above = Plane("above", 0.4, np.array([0.0, 0.0, 0.006]), np.array([0.0, 0.0, -1.0]))
    x = np.array([[0.0, 0.0, 0.003]])
    for pair in ([low, tilted], [low, above]):
        contacts = find_contacts(pair, x, THICKNESS)
        assert len(contacts) == 1 and not contacts.doubled.any()


def test_a_penetration_next_to_a_second_obstacle_keeps_both():
    obstacles = _table_and_wall()
    start = np.array([[-0.006, 0.0, 0.004]])
    end = np.array([[0.002, 0.0, 0.003]])          # ended inside the wall, on the table
    missed = penetrations(obstacles, start, end, THICKNESS)
    assert missed.doubled.all() and missed.hold.all()
    np.testing.assert_allclose(missed.normals[0], [-1.0, 0.0, 0.0])
    np.testing.assert_allclose(missed.second.normals[0], [0.0, 0.0, 1.0])
    # Distances from the start position to each tangent plane, less the thickness.
    assert missed.distance[0] == pytest.approx(0.006 - THICKNESS)
    assert missed.second.distance[0] == pytest.approx(0.004 - THICKNESS)
    assert not missed.second.hold[0]              # 3 mm above the table: releasable


def test_two_normals_land_filter_and_split_impulses():
    rng = np.random.default_rng(4)
    n1 = rng.normal(size=(20, 3))
    n2 = np.cross(n1, rng.normal(size=(20, 3))) + 0.3 * n1
    n1 /= np.linalg.norm(n1, axis=1)[:, None]
    n2 /= np.linalg.norm(n2, axis=1)[:, None]
    two = TwoNormals(n1, n2)
    v = rng.normal(size=(20, 3))
    targets = rng.normal(size=(20, 2))
    landed = v + two.landing(v, targets)
    np.testing.assert_allclose(np.einsum("kd,kd->k", landed, n1), targets[:, 0], atol=1e-12)
    np.testing.assert_allclose(np.einsum("kd,kd->k", landed, n2), targets[:, 1], atol=1e-12)
    free = two.free_projectors()
    np.testing.assert_allclose(np.einsum("kab,kb->ka", free, n1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("kab,kb->ka", free, n2), 0.0, atol=1e-12)
    line = np.cross(n1, n2)
    np.testing.assert_allclose(np.einsum("kab,kb->ka", free, line), line, atol=1e-12)
    r = rng.normal(size=(20, 3))
    loads = two.normal_loads(r)
    rebuilt = loads[:, :1] * n1 + loads[:, 1:] * n2
    np.testing.assert_allclose(rebuilt, two.in_plane(r), atol=1e-12)
    # What is left is along the free line only.
    rest = r - rebuilt
    np.testing.assert_allclose(np.cross(rest, line), 0.0, atol=1e-12)


def test_releasing_keeps_the_obstacle_that_still_pushes():
    k = 4
    up, side = np.tile([0.0, 0.0, 1.0], (k, 1)), np.tile([-1.0, 0.0, 0.0], (k, 1))
    contacts = ContactSet(np.arange(k), up, np.full(k, 0.1), np.full(k, 0.4))
    contacts.second = ContactSet(np.arange(k), side, np.full(k, 0.2), np.full(k, 0.3))
    distance = np.column_stack([np.full(k, 0.1), np.full(k, 0.2)])
    # row 0: nothing pulls; 1: the first pulls; 2: the second pulls; 3: both pull
    first = np.array([False, True, False, True])
    second = np.array([False, False, True, True])
    out, d, keep = _release(contacts, distance, first, second)
    assert list(keep) == [True, True, True, False]
    assert list(out.doubled) == [True, False, False]
    np.testing.assert_array_equal(out.normals, [up[0], side[0], up[0]])
    np.testing.assert_array_equal(out.friction, [0.4, 0.3, 0.4])
    np.testing.assert_array_equal(d, [[0.1, 0.2], [0.2, 0.0], [0.1, 0.0]])
    # The input set is untouched.
    assert contacts.doubled.all() and (contacts.normals == up).all()


def _wedge_scene(**kw):
    """A 0.3 m cloth on a table; a box tilted 30° about y (its front face
    leans over the cloth, its normal points forward and 30° down) moves
    into it at 0.3 m/s: the face pushes the near edge down into the table."""
    turn = Rotation.from_euler("y", 30.0, degrees=True).as_quat()
    return scene_from_dict(dict(
        name="wedge",
        cloth=dict(width=0.3, height=0.3, base_blocks=[2, 2], level=3,
                   origin=[-0.15, -0.15, THICKNESS]),
        air=dict(density=0.0),
        obstacles=[dict(type="plane", name="table", friction=0.4),
                   dict(type="box", name="wedge", centre=[-0.3, 0.0, 0.02],
                        half_extents=[0.06, 0.3, 0.08], orientation=list(turn),
                        friction=0.2, waypoints=[[0.0, -0.3, 0.0, 0.02, *turn],
                                                 [1.0, 0.0, 0.0, 0.02, *turn]])],
        contact=dict(friction_rounds=20),
        simulation=dict(time_step=H, duration=1.0), **kw))


@pytest.mark.parametrize("lod", [False, True])
def test_a_wedge_pushing_the_cloth_into_the_table_lets_no_particle_into_either(lod):
    scene = _wedge_scene(lod=dict(enabled=lod, initial_level=1))
    sim = ClothSim(scene)
    start = sim.positions[:, 0].mean()
    tolerance = 0.25 * scene.contact.thickness
    doubled = 0
    for _ in range(60):
        stats = sim.step()
        table, wedge = sim.obstacles
        assert table.distance(sim.positions)[0].min() > -tolerance, (sim.time, lod)
        assert wedge.distance(sim.positions)[0].min() > -tolerance, (sim.time, lod)
        contacts = sim.contacts
        doubled += int(contacts.doubled.sum()) if contacts is not None else 0
        assert np.isfinite(sim.positions).all() and stats.time == pytest.approx(sim.time)
    assert doubled > 0                      # the corner was reached, and held
    assert sim.positions[:, 0].mean() - start > 0.05     # the cloth was pushed


def test_lod_keeps_detail_where_the_cloth_meets_a_second_obstacle():
    """A box pushing a flat cloth on a table: nothing curves, but the line
    where the box's face meets the cloth on the table is refined to
    ``lod.detail_level`` and stays refined; the rest stays coarse."""
    scene = scene_from_dict(dict(
        name="push", cloth=dict(width=0.4, height=0.4, base_blocks=[2, 2], level=4,
                                origin=[-0.2, -0.2, THICKNESS]),
        air=dict(density=0.0),
        obstacles=[dict(type="plane", name="table", friction=0.4),
                   dict(type="box", name="pusher", centre=[-0.3, 0.0, 0.03],
                        half_extents=[0.05, 0.3, 0.08], friction=0.3,
                        waypoints=[[0.0, -0.3, 0.0, 0.03], [1.0, 0.0, 0.0, 0.03]])],
        contact=dict(friction_rounds=30),
        lod=dict(enabled=True, initial_level=1, detail_level=4),
        simulation=dict(time_step=H, duration=1.0)))
    sim = ClothSim(scene)
    for _ in range(60):
        sim.step()
    box = sim.obstacles[1]
    near = box.distance(sim.positions)[0] < 2.0 * scene.contact.thickness
    assert near.sum() >= 3                       # the box is pushing the cloth
    touching = near[sim.triangles].any(axis=1)
    assert sim.triangle_levels[touching].min() >= 4
    assert len(sim.triangles) < 0.5 * 2 * 4 * 4 ** 4     # far from uniform level 4
