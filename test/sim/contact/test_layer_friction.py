"""Contact between layers acts on both of them (issue 15): equal and opposite
impulses, so that two free layers keep their momentum and friction between
them only dissipates.

The two-layer cases use one cloth made of two disconnected pieces (a small
patch lying on a larger sheet, which lies on a table): the cleanest contact
between two free layers, with no fold joining them."""

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.cloth import lumped_masses
from cloth_lod_ros.sim.scene.config import load_scene, scene_from_dict
from cloth_lod_ros.sim.contact.contacts import ContactSet
from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.contact.layer_reactions import _limit, receivers, spread
from cloth_lod_ros.sim.mesh.mesh48 import RestMesh, base_mesh, refine_uniform
from cloth_lod_ros.sim.integrate.state import ClothState
from cloth_lod_ros.tools.stress.intersect import intersecting_pairs

THICKNESS = 0.004
G = 9.81
H = 1 / 60


def _patch_on_sheet(mu, table_mu=0.0, level=3, speed=1.0):
    """A 0.25 m patch sliding at ``speed`` m/s (along x) on a 0.5 x 0.25 m
    sheet that lies at rest on a table of friction ``table_mu``; ``mu``
    between the layers.  Returns ``(sim, upper)`` (``upper``: the patch's
    particles)."""
    data = {"name": "patch_on_sheet",
            "cloth": {"width": 0.5, "height": 0.25, "base_blocks": [2, 1], "level": level,
                      "origin": [0.0, 0.0, THICKNESS]},
            "air": {"density": 0.0},
            "obstacles": [{"type": "plane", "centre": [0, 0, 0], "normal": [0, 0, 1],
                           "friction": table_mu}],
            "simulation": {"time_step": H, "duration": 1.0},
            "self_collision": {"enabled": True, "thickness": THICKNESS, "friction": mu},
            "lod": {"enabled": False}}
    sim = ClothSim(scene_from_dict(data))
    sheet = refine_uniform(base_mesh(0.5, 0.25, 2, 1), level)
    patch = refine_uniform(base_mesh(0.25, 0.25, 1, 1), level)
    n = sheet.vertex_count
    # Two pieces in one mesh; the patch's material coordinates are moved far
    # away (rest shapes and masses only see differences; self-collision sees
    # two layers where the material is far apart).
    mesh = RestMesh(np.vstack([sheet.uv, patch.uv + [10.0, 0.0]]),
                    np.vstack([sheet.triangles, patch.triangles + n]),
                    np.concatenate([sheet.levels, patch.levels]), 10.25, 0.25)
    sim.mesh = mesh
    sim.elements = precompute(mesh)
    sim.masses = lumped_masses(mesh.uv, mesh.triangles, sim.scene.material.density)
    sim.vertex_ids = np.arange(mesh.vertex_count)
    sim.solver.reset_topology(sim.elements, mesh.uv)
    sim.self_collision.set_topology(sim.elements.triangles, mesh.uv)
    x = np.zeros((mesh.vertex_count, 3))
    x[:n, :2], x[:n, 2] = sheet.uv, THICKNESS
    x[n:, :2], x[n:, 2] = patch.uv + [0.05, 0.0], 2 * THICKNESS      # on the sheet
    v = np.zeros_like(x)
    v[n:, 0] = speed
    sim.state = ClothState(x, v, 0.0)
    upper = np.arange(mesh.vertex_count) >= n
    return sim, upper


def _mean_vx(sim, rows):
    m = sim.masses[rows]
    return float(m @ sim.velocities[rows, 0] / m.sum())


def test_friction_between_free_layers_conserves_momentum_and_stops_the_sliding():
    mu = 0.3
    sim, upper = _patch_on_sheet(mu)
    m = sim.masses
    p0 = m @ sim.velocities
    mass_up, mass_low = m[upper].sum(), m[~upper].sum()
    common = p0[0] / m.sum()
    history = []
    for _ in range(45):
        sim.step()
        # A frictionless table and no air: nothing outside the cloth acts
        # along the table, so the momentum of the two layers is conserved.
        # Both layers' impulses come out of the same solve, so it holds to
        # rounding (the direct solver; 1e-9 of p0 leaves room for its
        # round-off over 45 steps).
        p = m @ sim.velocities
        assert abs(p[0] - p0[0]) <= 1e-9 * abs(p0[0])
        assert abs(p[1]) <= 1e-9 * abs(p0[0])
        history.append((_mean_vx(sim, upper), _mean_vx(sim, ~upper)))
        assert not len(intersecting_pairs(sim.positions, sim.triangles))
    up, low = np.array(history).T
    # Sliding (the first 10 steps, relative speed above 0.5 m/s): the patch
    # decelerates at μ g and the sheet, pushed by the reaction, accelerates at
    # μ g m_patch/m_sheet (each within 3 %: the normal load is the patch's
    # weight; a step of the sliding phase checked one by one).
    decel = -np.diff(np.concatenate([[1.0], up[:10]])) / H
    accel = np.diff(np.concatenate([[0.0], low[:10]])) / H
    assert np.allclose(decel, mu * G, rtol=0.03)
    assert np.allclose(accel, mu * G * mass_up / mass_low, rtol=0.03)
    # The sliding stops: both move with the common velocity p/M.  (Averaged over
    # the last 15 steps: the resting layers keep a stick-slip jitter of about
    # 1 cm/s - measured -0.7..+0.9 cm/s on the main of 2026-11-28, +1.6 cm/s
    # with 2 Newton iterations - so one step's value is a coin toss at 1 cm/s;
    # any change to contact that moves a trajectory by round-off flips it.)
    assert np.mean(up[-15:] - low[-15:]) == pytest.approx(0.0, abs=0.02)
    assert np.mean(up[-15:]) == pytest.approx(common, abs=0.01)
    assert np.mean(low[-15:]) == pytest.approx(common, abs=0.01)


def test_a_sheet_held_by_table_friction_passes_the_reaction_to_the_table():
    """With friction on the table the sheet stays put (the table takes the
    reaction through the sheet's own contact); the patch still decelerates
    at μ g and stops on it."""
    mu = 0.3
    sim, upper = _patch_on_sheet(mu, table_mu=0.8)
    up = []
    for _ in range(25):
        sim.step()
        up.append(_mean_vx(sim, upper))
        assert abs(_mean_vx(sim, ~upper)) < 1e-3
    decel = -np.diff(np.concatenate([[1.0], up[:10]])) / H
    assert np.allclose(decel, mu * G, rtol=0.03)
    assert abs(up[-1]) < 0.01


def test_without_friction_the_patch_slides_on_and_the_sheet_stays():
    sim, upper = _patch_on_sheet(0.0)
    for _ in range(10):
        sim.step()
    assert _mean_vx(sim, upper) == pytest.approx(1.0, abs=1e-3)
    assert abs(_mean_vx(sim, ~upper)) < 1e-3


def test_friction_between_layers_takes_energy_it_never_gives():
    """The sheet slides under a patch resting on it: friction speeds the
    patch up and slows the sheet down until they move together, and the
    total energy only falls.  (One-sided, the patch was pulled to the
    sheet's speed and the sheet kept its own: 42 % more energy.)"""
    sim, upper = _patch_on_sheet(0.3, speed=0.0)
    sim.state.velocities[~upper, 0] = 1.0
    m = sim.masses
    p0 = m @ sim.velocities
    energy = [sum(sim.energy().values())]
    for _ in range(40):
        sim.step()
        energy.append(sum(sim.energy().values()))
    # Never above the start, and once the layers move together no rise
    # above the lowest energy so far of more than 1e-3 of it: the jitter of
    # two stuck layers, each contact holding its particle to its own pair's
    # velocity (measured 8e-5 here, 0 while they slide).
    energy = np.array(energy)
    assert energy.max() <= energy[0]
    assert np.max(energy - np.minimum.accumulate(energy)) <= 1e-3 * energy[0]
    assert energy[-1] < 0.8 * energy[0]
    common = p0[0] / m.sum()
    assert _mean_vx(sim, upper) == pytest.approx(common, abs=0.01)
    assert _mean_vx(sim, ~upper) == pytest.approx(common, abs=0.01)


def test_the_reaction_goes_to_the_other_side_weighted_and_never_to_held_particles():
    """``−w_j P`` on each other-side particle, summed over the contacts, held
    particles left out; an obstacle contact has no other side."""
    rows = np.array([0, 5, 7])
    partners = np.array([[1, 2, 3], [6, 6, 6], [0, 0, 0]])
    weights = np.array([[0.5, 0.3, 0.2], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    contacts = ContactSet(rows, np.tile([0.0, 0.0, 1.0], (3, 1)), np.zeros(3), np.ones(3),
                          partners=partners, partner_weights=weights)
    takes = receivers(contacts, np.array([3]), 8)
    assert np.flatnonzero(takes).tolist() == [1, 2, 6]
    applied = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 4.0], [9.0, 9.0, 9.0]])
    out = spread(contacts, applied, takes)
    assert np.allclose(out[1], -0.5 * applied[0]) and np.allclose(out[2], -0.3 * applied[0])
    assert np.allclose(out[6], -applied[1])
    assert not out[[0, 3, 4, 5, 7]].any()        # own rows, held, untouched
    # Where nothing is held the layers exchange exactly opposite impulses.
    everything = spread(contacts, applied, np.ones(8, bool))
    assert np.allclose(everything.sum(axis=0), -(weights.sum(axis=1)[:, None] * applied).sum(0))
    obstacle_only = ContactSet(rows, contacts.normals, np.zeros(3), np.ones(3))
    assert receivers(obstacle_only, np.array([3]), 8) is None


def test_a_share_never_throws_a_particle_past_the_layer_pushing_it():
    """The limit on each share ``ΔV`` (m/s): up to the pushing contacts'
    relative velocity ``d`` plus the slack, and never further from ``d`` than
    it was plus the slack, whatever the size of the reaction; nothing cut
    within that (friction dragging a layer, a landing)."""
    slack = 0.5
    towards = np.array([[1.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0],
                        [1.0, 0, 0]])
    change = np.array([[0.5, 0, 0], [50.0, 0, 0], [0.0, 3.0, 0], [-5.0, 0, 0], [0, 0, 0],
                       [1.0, 0.2, 0]])
    scale = _limit(change, towards, slack)
    assert scale[0] == 1.0 and scale[4] == 1.0 and scale[5] == 1.0
    assert np.linalg.norm(scale[1] * change[1]) == pytest.approx(1.0 + slack)
    assert np.linalg.norm(scale[2] * change[2]) == pytest.approx(slack)   # at rest
    assert np.linalg.norm(scale[3] * change[3] - towards[3]) == pytest.approx(1.0 + slack)
    new = scale[:, None] * change
    assert np.all(np.linalg.norm(new, axis=1) <= np.linalg.norm(towards, axis=1) + slack + 1e-12)
    assert np.all(np.linalg.norm(new - towards, axis=1)
                  <= np.linalg.norm(towards, axis=1) + slack + 1e-12)


def test_friction_acts_on_the_upper_side_of_a_contact_only():
    """Both layers of a contact are constrained against each other (each
    vertex near the other layer has its own pair); friction goes on the side
    above, the one below takes the reaction.  With friction on both, both
    stuck to the pair's velocity at the start of the step and dragged the
    rest of the cloth as if infinitely heavy."""
    sim, upper = _patch_on_sheet(0.3, level=2)
    sc = sim.self_collision
    x, v, m = sim.positions, sim.velocities, sim.masses
    sc.set_topology(sim.triangles, sim.mesh.uv)
    pairs = sc.proximity(x, v, H)
    none = np.zeros(len(m), bool)
    both = sc.constraints(pairs, v, m, none, np.zeros(0, np.int64))
    up = sc.constraints(pairs, v, m, none, np.zeros(0, np.int64), up=np.array([0, 0, 1.0]))
    below = ~upper[up.indices]
    assert below.any() and (~below).any()
    assert np.all(up.friction[~below] == 0.3) and np.all(up.friction[below] == 0.0)
    assert np.all(both.friction == 0.3)
    # The pair's common velocity is the mean of the sides' (equal masses per
    # area), the same for every pair of the overlap.
    assert np.allclose(up.velocity[:, 0], 0.5)


def test_friction_between_layers_adds_no_energy_to_a_crumpling_cloth():
    """``drop_crumple`` as configured (μ = 0.3 between the layers, level 5)
    with LOD off, the whole 2.5 s: nothing drives the cloth, so its energy
    (kinetic + gravity + elastic) never exceeds the initial one.  With
    one-sided friction this run peaked at 3.4x the initial energy (1.43 J
    of 0.42 J) and ended at 1.8x; frictionless it stayed below."""
    sim = ClothSim(load_scene("drop_crumple", ["lod.enabled=false"]))
    assert sim.scene.self_collision.friction == 0.3 and sim.max_level == 5
    initial = sum(sim.energy().values())
    energy = []
    while sim.time < sim.scene.simulation.duration - 1e-9:
        sim.step()
        energy.append(sum(sim.energy().values()))
    # 1e-9 of the initial energy: rounding of the energy sums (the largest
    # energy after the start, the first step, is 2e-8 below it).
    assert max(energy) <= initial * (1.0 + 1e-9)
    assert sim.self_collision.counters.with_pairs > 100
