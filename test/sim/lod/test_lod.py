"""Adaptive level of detail: criterion, policy and whole-run behaviour."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim.scene.config import SceneError, load_scene, scene_from_dict
from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.mesh.operations import Merge, Split
from cloth_lod_ros.sim.lod.policy import curvature_estimate, hinge_measures
from cloth_lod_ros.sim.mesh.sampling import rms_and_max_distance
from cloth_lod_ros.sim import ClothSim
from tolerances import assert_close_ulps, sum_floor

G = np.array([0.0, 0.0, -9.81])


def lod_scene(max_level=4, initial_level=0, gravity=(0, 0, -9.81), pins=(), **lod):
    cfg = {"enabled": True, "initial_level": initial_level}
    cfg.update(lod)
    return scene_from_dict({
        "name": "lod_test",
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": max_level},
        "material": {"air_drag": 0.0},
        "air": {"density": 0.0},        # no air: test/sim/physics/test_air.py tests it
        "pins": [dict(p) for p in pins],
        "simulation": {"time_step": 1 / 60, "duration": 1.0, "gravity": list(gravity)},
        "solver": {"tolerance": 1e-9, "max_iterations": 5000},
        "lod": cfg,
    })


def total_momentum(sim):
    return (sim.masses[:, None] * sim.velocities).sum(axis=0)


# -- the criterion ---------------------------------------------------------------

@settings(max_examples=50, deadline=None)
@given(st.floats(1e-3, np.pi - 1e-3), st.floats(1e-3, 1.0))
def test_deviation_is_the_papers_formula(theta, height):
    paper = height * (1 - np.cos(theta / 2)) / (2 * np.sin(theta / 2))
    np.testing.assert_allclose(curvature_estimate(np.array([theta]), np.array([height])),
                               paper, rtol=1e-8)   # 1 - cos cancels in the paper form
    np.testing.assert_allclose(curvature_estimate(np.array([-theta]), np.array([height])),
                               paper, rtol=1e-8)   # 1 - cos cancels in the paper form
    assert curvature_estimate(np.array([0.0]), np.array([height]))[0] == 0.0


def test_deviation_of_a_cylinder_is_its_sagitta():
    """On a cylinder of radius R the paper's d is the arc's distance from the flat pair."""
    from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform
    mesh = refine_uniform(base_mesh(1.0, 1.0, 4, 4), 4)
    radius = 0.3
    u, v = mesh.uv[:, 0], mesh.uv[:, 1]
    x = np.column_stack([radius * np.sin(u / radius), v, radius * (1 - np.cos(u / radius))])
    el = precompute(mesh)
    m = hinge_measures(el, 1e-3, x, np.zeros_like(x))
    curved = m.deviation > 1e-9
    # Edges along v (axis direction) with apexes a leg's length away: d ≈ s²/(8R)·(1/2)...
    # whatever the edge, d must be below the sagitta of the two triangles' span.
    span = 2 * (1.0 / 16)
    assert np.all(m.deviation <= span**2 / (8 * radius) + 1e-12)
    assert curved.sum() > 0
    np.testing.assert_allclose(m.rate, 0.0)


# -- whole-run behaviour --------------------------------------------------------

def test_flat_still_cloth_never_refines_and_coarsens_to_the_base():
    sim = ClothSim(lod_scene(max_level=5, gravity=(0, 0, 0), initial_level=2))
    # Two merge waves, each after min_lifetime (12 steps), at checks every 4 steps.
    for _ in range(48):
        s = sim.step()
        assert s.refines == 0
    assert sim.mesh.triangle_count == 32           # flat and still: nothing to model
    # Still up to rounding: the bending force -Q x of a flat sheet is zero only up
    # to the round-off of summing its stencils (~1e-16 of |x| per step).
    np.testing.assert_allclose(sim.velocities, 0.0, atol=1e-12)


def test_free_fall_with_lod_falls_at_g_and_stays_flat():
    """A non-uniform adaptive mesh (graded masses) still falls rigidly at g, also
    when it is split and merged mid-fall."""
    sim = ClothSim(lod_scene(max_level=5, initial_level=1))
    rng = np.random.default_rng(1)
    for _ in range(12):                       # make the mesh genuinely graded
        sim.refine(int(rng.choice(sim.hierarchy.active_triangles())))
    assert len(np.unique(sim.masses.round(12))) > 3
    h = sim.time_step
    for step in range(30):
        if step % 5 == 2:                      # topology changes during the fall
            sim.refine(int(rng.choice(sim.hierarchy.active_triangles())))
            edges = sim.hierarchy.mergeable_edges()
            sim.apply_mesh_operations([Merge(edges[rng.integers(len(edges))])])
        s = sim.step()
        assert s.refines == 0                  # flat: the criterion never fires
    np.testing.assert_allclose(sim.velocities, np.tile(30 * h * G, (len(sim.masses), 1)),
                               atol=1e-7)
    assert np.ptp(sim.positions[:, 2]) < 1e-7   # still flat and horizontal
    expected = sim.masses.sum() * 30 * h * G
    np.testing.assert_allclose(total_momentum(sim), expected, rtol=0,
                               atol=1e-9 * np.abs(expected).max())


def test_lod_run_conserves_mass_and_holds_pins_exactly():
    cfg = load_scene("hang_two_corners", ["cloth.level=4", "simulation.duration=1.5"])
    sim = ClothSim(cfg)
    total = cfg.material.density * 1.0
    targets = {p.name: p.anchor.copy() for p in sim.pins}
    changes = 0
    for _ in range(90):
        s = sim.step()
        changes += s.refines + s.merges
        assert sim.masses.sum() == pytest.approx(total, rel=1e-13)
        for p in sim.pins:
            np.testing.assert_array_equal(sim.positions[p.vertex], targets[p.name])
        assert max(np.flatnonzero(s.triangles_per_level)) <= 4
    assert changes > 20                      # the mesh really adapted
    sim.hierarchy.check()


def test_settled_drape_stops_changing_topology():
    """Hysteresis: once the cloth hangs still, splits and merges stop.  (Air
    drag 3 /s: the last split or merge is at 2.6 s, the kinetic energy below
    1e-5 J from 2.9 s; the last 2 s of 6 s start 1.4 s after the last change.)"""
    cfg = load_scene("hang_two_corners", ["cloth.level=5", "material.air_drag=3.0"])
    sim = ClothSim(cfg)
    ops = []
    for _ in range(int(6.0 / sim.time_step)):
        s = sim.step()
        ops.append(s.refines + s.merges)
    ops = np.array(ops)
    second = int(1.0 / sim.time_step)
    assert ops[:2 * second].sum() > 50                     # busy while swinging
    assert ops[-2 * second:].sum() == 0                     # quiet at rest
    assert sim.stats[-1].kinetic_energy < 1e-5


@pytest.mark.parametrize("axis", [0, 1])
def test_folded_band_refines_only_where_it_curves(axis):
    """A sheet bent round a cylinder over a band of u (or v) refines in the band only."""
    sim = ClothSim(lod_scene(max_level=5, initial_level=2, gravity=(0, 0, 0)))
    lo, hi, radius = 0.4, 0.6, 0.15

    def bend(uv):
        s = uv[:, axis]
        t = uv[:, 1 - axis]
        arc = np.clip(s, lo, hi) - lo
        along = np.where(s < lo, s, lo + radius * np.sin(arc / radius)
                         + np.where(s > hi, (s - hi) * np.cos((hi - lo) / radius), 0))
        up = np.where(s < lo, 0.0, radius * (1 - np.cos(arc / radius))
                      + np.where(s > hi, (s - hi) * np.sin((hi - lo) / radius), 0))
        out = np.zeros((len(uv), 3))
        out[:, axis], out[:, 1 - axis], out[:, 2] = along, t, up
        return out

    # Impose the shape, then let the policy refine (no physics step in between).
    for _ in range(4):
        sim.state.positions[:] = bend(sim.rest_uv)
        sim.adapt()
    mesh = sim.mesh
    centroid = mesh.uv[mesh.triangles].mean(axis=1)[:, axis]
    refined = mesh.levels > 2
    assert refined.sum() > 10
    margin = 0.25                       # one base block of grading either side
    assert np.all((centroid[refined] > lo - margin) & (centroid[refined] < hi + margin))
    in_band = (centroid > lo) & (centroid < hi)
    assert mesh.levels[in_band].min() > 2           # the whole band refined
    far = (centroid < lo - margin) | (centroid > hi + margin)
    assert np.all(mesh.levels[far] == 2)            # flat parts untouched


def test_young_triangles_are_not_merged():
    sim = ClothSim(lod_scene(max_level=4, gravity=(0, 0, 0), min_lifetime=0.5))
    sim.refine(int(sim.hierarchy.active_triangles()[5]))
    counts = []
    for _ in range(45):                       # 0.75 s: flat and still, so mergeable
        counts.append(sim.step().merges)
    first_merge = int(np.flatnonzero(counts)[0])
    assert first_merge * sim.time_step >= 0.5 - 1e-9
    assert sim.mesh.triangle_count == 32


def test_moving_hinges_are_not_merged():
    """Flat but turning hinges (large dθ/dt) are not simplified."""
    sim = ClothSim(lod_scene(max_level=4, gravity=(0, 0, 0), min_lifetime=0.0,
                             max_hinge_rate=0.1))
    sim.refine(int(sim.hierarchy.active_triangles()[5]))
    # A bending velocity field (θ stays ~0 in the first step, but dθ/dt is large).
    sim.state.velocities[:, 2] = 2.0 * (sim.rest_uv[:, 0] - 0.5) ** 2
    s = sim.step()
    assert s.merges == 0


def test_pinned_split_particle_is_never_merged():
    sim = ClothSim(lod_scene(max_level=3, gravity=(0, 0, 0), min_lifetime=0.0,
                             pins=[{"name": "p", "uv": [0.125, 0.125]}], initial_level=0))
    # (0.125, 0.125) is the midpoint made by splitting the base block at the origin.
    assert sim.pins[0].snap_distance > 0
    sim2 = ClothSim(lod_scene(max_level=3, gravity=(0, 0, 0), min_lifetime=0.0,
                              initial_level=1, pins=[{"name": "p", "uv": [0.125, 0.125]}]))
    assert sim2.pins[0].snap_distance == 0.0
    node = sim2.pins[0].node
    for _ in range(20):
        sim2.step()
        assert sim2.hierarchy.vertex_active[node]
    assert sim2.mesh.triangle_count < 64             # the rest did coarsen


def test_lod_switch_and_level_meaning():
    adaptive = load_scene("hang_two_corners", ["cloth.level=3"])
    assert adaptive.lod.enabled
    sim = ClothSim(adaptive)
    assert sim.mesh.vertex_count == 25               # starts from the paper's base mesh
    uniform = ClothSim(load_scene("hang_two_corners", ["cloth.level=6", "lod.enabled=false"]))
    assert uniform.mesh.vertex_count == 33 * 33 and uniform.hierarchy is None
    with pytest.raises(SceneError, match="lod.coarsen_threshold"):
        load_scene("hang_two_corners", ["lod.coarsen_threshold=0.01"])
    with pytest.raises(SceneError, match="lod.initial_level"):
        load_scene("hang_two_corners", ["cloth.level=2", "lod.initial_level=3"])
    with pytest.raises(SceneError, match="lod.enabled"):
        load_scene("hang_two_corners", ["lod.enabled=maybe"])


def test_adaptive_hang_stays_close_to_uniform_level_6():
    """The adaptive run (max level 6) against the uniform 33 x 33 run, at the same
    material points after 1 s: RMS within 6 mm (measured 2.1 mm at 1 s, 2.2 mm at
    3 s with the default thresholds; see README)."""
    grid = np.linspace(0.0, 1.0, 11)
    points = np.array([[u, v] for v in grid for u in grid])
    results = {}
    for lod in ("true", "false"):
        sim = ClothSim(load_scene("hang_two_corners", [f"lod.enabled={lod}"]))
        sim.run(1.0)
        results[lod] = sim.sample(points)
    rms, worst = rms_and_max_distance(results["true"], results["false"])
    assert rms < 0.006 and worst < 0.02
    # And it is not trivially close: the cloth moved far from its start.
    start = np.column_stack([points, np.ones(len(points))])
    assert rms_and_max_distance(results["false"], start)[0] > 0.2


def test_split_then_merge_leaves_the_simulation_state_unchanged():
    sim = ClothSim(lod_scene(max_level=4, initial_level=2))
    for _ in range(5):
        sim.step()
    before = (sim.positions.copy(), sim.velocities.copy(), sim.masses.copy(),
              sim.triangles.copy())
    ops = sim.refine(int(sim.hierarchy.active_triangles()[7]))
    assert len(ops) >= 1 and sim.mesh.triangle_count > before[3].shape[0]
    sim.apply_mesh_operations([op.inverse() for op in reversed(ops)])
    after = (sim.positions, sim.velocities, sim.masses, sim.triangles)
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)
    assert isinstance(ops[-1], Split)


def test_criterion_reuses_the_force_evaluation_exactly():
    """The step hands its own force evaluation to the criterion: same numbers.
    The evaluation here is the numpy reference's and the fresh measures may be
    the compiled kernels' (numpy's arctan2 against the C library's), so they
    agree to the tolerances of test/tolerances.py, not bit for bit."""
    from cloth_lod_ros.sim.physics.forces import evaluate
    sim = ClothSim(load_scene("hang_two_corners", ["cloth.level=4"]))
    for _ in range(20):
        sim.step()
    x, v = sim.positions, sim.velocities
    ev = evaluate(sim.elements, sim.scene.material, x, v, 1.0, 1.0)
    fresh = hinge_measures(sim.elements, 1e-3, x, v)
    reused = hinge_measures(sim.elements, 1e-3, x, v, ev)
    hv = sim.elements.hinge_vertices
    rate_terms = (np.abs(ev.hinge_gradient) * np.abs(v[hv])).sum(axis=(1, 2))
    assert_close_ulps(reused.deviation, fresh.deviation, err_msg="deviation")
    assert_close_ulps(reused.bend_force, fresh.bend_force, err_msg="bend_force")
    assert_close_ulps(reused.rate, fresh.rate, abs_floor=sum_floor(rate_terms, 12),
                      err_msg="rate")
    assert fresh.deviation.max() > 0
    # The solver's cache is keyed on the state, not on the object holding it.
    def evaluation():
        return sim.solver.evaluate(sim.elements, sim.state.positions, sim.state.velocities,
                                   sim.time_step)[0]

    first = evaluation()
    sim.state.positions[0, 2] += 0.01
    second = evaluation()
    assert second is not first
    assert evaluation() is second


# -- cadence: batched merges, refinement look-ahead and rounds ---------------------

def test_merges_wait_for_their_interval_and_refinement_does_not():
    """``merge_interval`` batches merges to every k-th check (one new pattern
    instead of k); refinement still happens at every check."""
    sim = ClothSim(load_scene("hang_two_corners", ["cloth.level=5", "lod.check_interval=1", "lod.merge_interval=3"]))
    stats = [sim.step() for _ in range(int(2.0 / sim.time_step))]
    merge_steps = [s.step_index for s in stats if s.merges]
    refine_steps = [s.step_index for s in stats if s.refines]
    assert len(merge_steps) > 5 and all(i % 3 == 0 for i in merge_steps)
    assert any(i % 3 for i in refine_steps)            # refinement is not held back


def _swinging(check_interval=1):
    sim = ClothSim(load_scene("hang_two_corners",
                              ["cloth.level=5", f"lod.check_interval={check_interval}"]))
    for _ in range(12):
        sim.step()
    return sim


def test_lookahead_refines_hinges_about_to_cross_the_threshold():
    """With ``lookahead`` τ a hinge is refined when ``θ + τ θ̇`` is over the
    threshold; with τ = 0 the decision is the paper's."""
    sim = _swinging()
    h = sim.hierarchy
    args = (h, sim.elements, sim.vertex_ids, sim.triangle_ids, sim.positions, sim.velocities,
            sim.masses, sim.time, sim._held_nodes())
    now = sim.lod_policy.decide(*args, simplify=False)
    zero = sim.lod_policy.decide(*args, simplify=False, lookahead=0.0)
    ahead = sim.lod_policy.decide(*args, simplify=False, lookahead=0.1)
    assert now.refine == zero.refine
    assert set(now.refine) < set(ahead.refine)          # strictly more, nothing lost
    # Every extra triangle belongs to a hinge whose extrapolated deviation is over.
    m = hinge_measures(sim.elements, sim.scene.material.bend_stiffness, sim.positions,
                       sim.velocities)
    extrapolated = curvature_estimate(np.clip(m.angle + 0.1 * m.rate, -np.pi, np.pi), m.height)
    over = extrapolated > sim.scene.lod.refine_threshold
    flagged = set(sim.triangle_ids[sim.elements.hinge_triangles[over].ravel()].tolist())
    extra = set(ahead.refine) - set(now.refine)
    assert extra <= flagged | set(now.refine)


def test_a_pass_in_rounds_refines_as_deep_as_that_many_checks():
    """``adapt(rounds=k)`` refines the triangles a round made again while they
    are still too curved: from a coarse mesh it reaches deeper levels than one
    round, never beyond the maximum, and the mesh stays a valid 4-8 mesh."""
    def adapted(rounds):
        sim = ClothSim(lod_scene(max_level=6, initial_level=1))
        u, v = sim.rest_uv[:, 0], sim.rest_uv[:, 1]
        radius = 0.25                                   # rolled about the v axis
        sim.state.positions[:] = np.column_stack(
            [radius * np.sin(u / radius), v, radius * (1 - np.cos(u / radius))])
        sim.adapt(simplify=False, rounds=rounds)
        sim.hierarchy.check()
        return sim
    one, three = adapted(1), adapted(3)
    assert three.triangle_levels.max() <= 6
    assert three.mesh.triangle_count > one.mesh.triangle_count
    # Deeper where it curves (the pin patches are at level 6 from the start).
    assert three.triangle_levels.mean() > one.triangle_levels.mean() + 0.2


def test_checking_every_few_steps_stays_close_to_checking_every_step():
    """A mesh checked every 4 steps (look-ahead and rounds) follows the same
    motion as one checked every step: within the adaptive mesh's own error."""
    every = ClothSim(load_scene("hang_two_corners", ["cloth.level=5", "lod.check_interval=1"]))
    fourth = ClothSim(load_scene("hang_two_corners", ["cloth.level=5", "lod.check_interval=4"]))
    uv = np.stack(np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 1, 11)), -1).reshape(-1, 2)
    for _ in range(int(1.0 / every.time_step)):
        every.step()
        fourth.step()
    rms, _ = rms_and_max_distance(every.sample(uv), fourth.sample(uv))
    assert rms < 0.01                                   # m, on a 1 m cloth
    assert sum(s.refines + s.merges > 0 for s in fourth.stats) \
        < 0.5 * sum(s.refines + s.merges > 0 for s in every.stats)
