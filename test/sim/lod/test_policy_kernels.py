"""The compiled LOD criterion (cloth_lod_ros.sim.lod.policy_kernels) against the numpy
reference: the hinge measures and the merge energies to the tolerances of
test/tolerances.py (the angles come from numpy's arctan2/tan on one side and
the C library's on the other, which may differ by a few ULP on some CPUs), and
the decisions they make the same except for values within those tolerances of
a threshold.  Integer results (candidates, refine order from given
deviations, the tests (a)-(d) on given measures) are compared bitwise: the same
comparisons of the same floats."""

import copy
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.lod import policy as lod_policy, policy_kernels
from cloth_lod_ros.sim.lod import merge_energy_kernels
from cloth_lod_ros.sim.runtime import compiled
from cloth_lod_ros.sim.physics import hinges_kernels
from cloth_lod_ros.sim.scene.config import scene_from_dict
from cloth_lod_ros.sim.mesh.operations import Merge
from cloth_lod_ros.sim.lod.policy import LodPolicy
from cloth_lod_ros.sim.lod.merge_energy import merge_energy_change
from tolerances import assert_close_ulps, assert_lod_decisions_agree, energy_floor, sum_floor

pytestmark = [pytest.mark.skipif(not compiled.available, reason="numba not installed"),
              # degenerate inputs on purpose: the reference warns of its 0/0
              pytest.mark.filterwarnings("ignore::RuntimeWarning"),
              pytest.mark.usefixtures("kernels_restored")]



def _same(a, b):
    """Bitwise: for integer and boolean results, and for floats that are the
    same operations on the same operands (see test/tolerances.py)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    assert a.tobytes() == b.tobytes()


def _measures_close(ours, reference, rate_terms, lookahead=0.0):
    """Hinge measures of the kernels against the reference's: angle, deviation,
    bend force and height to a few ULP (they pass through arctan2 and tan), the
    rate to the rounding bound of its 12-term sum (whose terms' magnitudes
    ``rate_terms`` ``(h,)`` rad/s are given)."""
    for name in ("deviation", "bend_force", "angle", "height"):
        assert_close_ulps(getattr(ours, name), getattr(reference, name), err_msg=name)
    assert_close_ulps(ours.rate, reference.rate, abs_floor=sum_floor(rate_terms, 12),
                      err_msg="rate")


def _both(function, *args, **kwargs):
    """``function`` by the numpy reference, then by the kernels."""
    compiled.use(False)
    reference = function(*args, **kwargs)
    compiled.use(True)
    return reference, function(*args, **kwargs)


def _wide(rng, shape):
    """Random numbers over many magnitudes, so that any change of the order
    of a sum changes its rounding."""
    return rng.standard_normal(shape) * np.exp(rng.uniform(-12.0, 12.0, shape))


def test_einsum_order_is_the_one_the_kernels_reproduce():
    """The kernels sum in np.einsum's order on x86_64 numpy builds (two lanes,
    see the module docstring); another build may order or fuse (FMA) the
    products differently, which moves a sum by at most γ_n Σ|products|
    (test/tolerances.py): that bound is what holds everywhere, and what the
    comparisons with the reference allow."""
    rng = np.random.default_rng(0)
    a, b = _wide(rng, (4000, 3)), _wide(rng, (4000, 3))
    p = a * b
    assert_close_ulps(np.einsum("kd,kd->k", a, b),
                      ((0.0 + p[:, 0]) + p[:, 2]) + ((0.0 + p[:, 1]) + 0.0),
                      ulps=0, abs_floor=sum_floor(np.abs(p).sum(axis=1), 3))
    a2, b2 = _wide(rng, (4000, 2)), _wide(rng, (4000, 2))
    p2 = a2 * b2
    assert_close_ulps(np.einsum("hd,hd->h", a2, b2), (p2[:, 0] + 0.0) + (p2[:, 1] + 0.0),
                      ulps=0, abs_floor=sum_floor(np.abs(p2).sum(axis=1), 2))


def _criterion_inputs(rng, count, degenerate):
    n = max(4, count)
    hv = np.array([rng.choice(n, 4, replace=False) for _ in range(count)],
                  dtype=np.int64).reshape(-1, 4)
    grad = _wide(rng, (count, 4, 3))
    theta = rng.uniform(-np.pi, np.pi, count)
    v = _wide(rng, (n, 3))
    if degenerate and count:
        grad[0] = 0.0                       # zero gradients: infinite height
        theta[-1] = np.nan                  # a degenerate hinge's angle
        grad[count // 2, 1] = np.nan
        v[hv[0, 0]] = 0.0
    elements = SimpleNamespace(hinge_vertices=hv, hinge_weight=rng.uniform(0.1, 2.0, count))
    return elements, SimpleNamespace(hinge_angle=theta, hinge_gradient=grad), v


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(0, 300),
       lookahead=st.sampled_from([0.0, 1e-3, 0.05, 10.0]), degenerate=st.booleans())
def test_hinge_criterion_matches_the_reference(seed, count, lookahead, degenerate):
    """Given angles and gradients (an evaluation's): the same inputs to both, so
    only tan (the deviation) differs by implementation."""
    rng = np.random.default_rng(seed)
    elements, evaluation, v = _criterion_inputs(rng, count, degenerate)
    (m0, d0), (m1, d1) = _both(lod_policy._criterion, elements, 3e-5, None, v, evaluation, lookahead)
    hv = elements.hinge_vertices
    rate_terms = (np.abs(evaluation.hinge_gradient) * np.abs(v[hv])).sum(axis=(1, 2))
    _measures_close(m1, m0, rate_terms)
    # The look-ahead deviation: θ + τ θ̇ carries θ̇'s tolerance by at most L/4 per rad.
    rate_floor = sum_floor(rate_terms, 12)
    assert_close_ulps(d1, d0, abs_floor=0.25 * np.nan_to_num(m0.height, posinf=0.0)
                      * lookahead * np.nan_to_num(rate_floor))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(0, 200),
       candidates=st.integers(0, 40), held_count=st.integers(0, 10))
def test_the_settled_young_and_held_tests_are_the_reference(seed, count, candidates,
                                                            held_count):
    """Tests (a)-(d) of LodPolicy.decide: its numpy lines against the kernel,
    with NaN measures, padding children and held particles."""
    rng = np.random.default_rng(seed)
    elements, evaluation, v = _criterion_inputs(rng, count, True)
    m, _ = lod_policy._criterion(elements, 3e-5, None, v, evaluation)
    n, pool = len(v), len(v) + 7
    config = SimpleNamespace(coarsen_threshold=float(np.nanmedian(m.deviation)) if count else 0.0,
                             max_hinge_rate=float(np.nanmedian(np.abs(m.rate))) if count else 0.0,
                             max_bend_force=float(np.nanmax(m.bend_force)) if count else 0.0)
    vertex_ids = np.sort(rng.choice(pool, n, replace=False))
    vertices = np.sort(rng.choice(vertex_ids, min(candidates, n), replace=False))
    kids = rng.integers(-1, 50, (len(vertices), 4))
    birth = rng.uniform(0.0, 2.0, 50)
    birth[rng.integers(0, 50)] = np.nan
    held = rng.choice(pool, held_count)
    cutoff = 1.0
    # The reference: LodPolicy.decide's numpy lines.
    unsettled = ((m.deviation >= config.coarsen_threshold)
                 | (np.abs(m.rate) >= config.max_hinge_rate)
                 | (m.bend_force >= config.max_bend_force))
    blocked = np.zeros(n, dtype=bool)
    blocked[elements.hinge_vertices[unsettled].ravel()] = True
    births = np.where(kids >= 0, birth[np.maximum(kids, 0)], -np.inf)
    young = (np.maximum(np.maximum(births[:, 0], births[:, 1]),
                        np.maximum(births[:, 2], births[:, 3])) > cutoff)
    is_held = np.zeros(pool, dtype=bool)
    is_held[np.asarray(held, dtype=np.int64)] = True
    reference = ~(blocked[np.searchsorted(vertex_ids, vertices)] | young | is_held[vertices])
    compiled.use(True)
    _same(reference, policy_kernels.mergeable(elements.hinge_vertices, m, config, vertex_ids,
                                              vertices, kids, birth, cutoff, held, pool))
    # An id the reference would reject: the kernel declines.
    assert policy_kernels.mergeable(elements.hinge_vertices, m, config, vertex_ids, vertices,
                                    kids, birth, cutoff, np.array([pool]), pool) is None


def _scene(max_level=5, gravity=(0.0, 0.0, -9.81)):
    return scene_from_dict({
        "name": "lod_kernels",
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [4, 4], "level": max_level},
        "simulation": {"time_step": 1 / 60, "duration": 1.0, "gravity": list(gravity)},
        "lod": {"enabled": True, "initial_level": 1, "min_lifetime": 0.0,
                "max_hinge_rate": 1e9, "max_bend_force": 1e9, "refine_threshold": 2e-3,
                "coarsen_threshold": 1.9e-3, "max_merge_speed": 1.0},
    })


_SIMS = {}


def _perturbed(seed, offset, speed, half=False):
    """An adaptive cloth with random refinements and a random state (cached);
    with ``half``, only its half u > 0.5 m is displaced (the other stays flat)."""
    key = (seed, offset, speed, half)
    if key not in _SIMS:
        sim = ClothSim(_scene())
        rng = np.random.default_rng(seed)
        for _ in range(20):
            sim.refine(int(rng.choice(sim.hierarchy.active_triangles())))
        noise = offset * rng.standard_normal(sim.positions.shape)
        if half:
            noise[sim.hierarchy.uv[sim.vertex_ids, 0] <= 0.5] = 0.0
        sim.state.positions[:] += noise
        sim.state.velocities[:] = speed * rng.standard_normal(sim.positions.shape)
        sim._sync_hierarchy()
        _SIMS[key] = sim
    return _SIMS[key]


def _merge_energy(sim, vertices, gravity=None):
    gravity = sim.scene.simulation.gravity if gravity is None else gravity
    return merge_energy_change(sim.hierarchy, sim.elements, sim.vertex_ids, sim.triangle_ids,
                               vertices, sim.positions, sim.velocities, sim.masses,
                               sim.scene.material, np.asarray(gravity, dtype=float))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 3), offset=st.sampled_from([0.0, 1e-6, 0.01, 0.2]),
       speed=st.sampled_from([0.0, 0.3]), pick=st.integers(0, 2**32 - 1),
       gravity=st.sampled_from([(0.0, 0.0, -9.81), (0.3, -9.7, 1.3), (0.0, 0.0, 0.0)]))
def test_merge_energies_match_the_reference(seed, offset, speed, pick, gravity):
    """Every candidate or a random subset (interior and border diamonds),
    under any gravity."""
    sim = _perturbed(seed, offset, speed)
    vertices, _ = sim.hierarchy.split_vertices()
    assert np.any(sim.hierarchy.vertex_parents[vertices, 1] < 0)      # a border one
    rng = np.random.default_rng(pick)
    if pick % 2:
        vertices = np.sort(rng.choice(vertices, rng.integers(1, len(vertices) + 1),
                                      replace=False))
    e0, e1 = _both(_merge_energy, sim, vertices, gravity)
    _energies_close(e1, e0, sim)


def _energies_close(ours, reference, sim):
    """Merge energies to tolerances.energy_floor (a fraction of the larger of
    |ΔE| and the bound ½ ρ A v²); the diamonds' areas to a few ULP."""
    bound = (0.5 * sim.scene.material.density * reference.area
             * sim.scene.lod.max_merge_speed ** 2)
    for name in ("total", "kinetic"):
        assert_close_ulps(getattr(ours, name), getattr(reference, name),
                          abs_floor=energy_floor(getattr(reference, name), bound),
                          err_msg=name)
    assert_close_ulps(ours.area, reference.area, err_msg="area")


@pytest.mark.parametrize("offset", [0.0, 0.01, 0.3])
def test_hinge_measures_of_a_mesh_match_the_reference(offset):
    """Without an evaluation (the angles computed in the kernel), flat to crumpled."""
    sim = _perturbed(2, offset, 0.3)
    m0, m1 = _both(lod_policy.hinge_measures, sim.elements, sim.scene.material.bend_stiffness,
                   sim.positions, sim.velocities)
    _, grad = hinges_kernels.hinge_angles(sim.positions, sim.elements.hinge_vertices,
                                          with_gradient=True)
    rate_terms = (np.abs(grad) * np.abs(sim.velocities[sim.elements.hinge_vertices])).sum(
        axis=(1, 2))
    _measures_close(m1, m0, rate_terms)


def test_merge_energies_of_no_candidates_and_a_collapsed_cloth():
    sim = _perturbed(0, 0.01, 0.3)
    for e in _both(_merge_energy, sim, np.zeros(0, dtype=np.int64)):
        assert e.total.shape == e.kinetic.shape == e.area.shape == (0,)
    # Every particle at one point and still: degenerate hinges (NaN angles).
    collapsed = SimpleNamespace(**{name: getattr(sim, name) for name in (
        "hierarchy", "elements", "vertex_ids", "triangle_ids", "velocities", "masses",
        "scene")}, positions=np.zeros_like(sim.positions))
    vertices, _ = sim.hierarchy.split_vertices()
    e0, e1 = _both(_merge_energy, collapsed, vertices)
    _energies_close(e1, e0, sim)


def test_a_candidate_outside_the_compact_mesh_goes_to_the_reference():
    """A pool id the compact ids lack: the kernels decline, the reference runs."""
    sim = _perturbed(1, 0.01, 0.3)
    vertices, _ = sim.hierarchy.split_vertices()
    compiled.use(True)
    missing = sim.vertex_ids[:-1]                 # the last compact particle is gone
    ok = merge_energy_kernels.merge_energies(sim.hierarchy, sim.elements, missing, sim.triangle_ids,
                                             vertices[-1:] * 0 + sim.vertex_ids[-1], sim.positions,
                                             sim.velocities, sim.masses, sim.scene.material,
                                             np.zeros(3))
    assert ok is None


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("held_count", [0, 5])
def test_decisions_are_the_reference_decisions(seed, held_count):
    """LodPolicy.decide, with held particles and the look-ahead: the same refine
    and merge lists and the same energies and bounds on both paths."""
    sim = _perturbed(seed, 0.02, 1e-4, half=True)
    vertices, _ = sim.hierarchy.split_vertices()
    held = np.sort(np.random.default_rng(seed).choice(vertices, held_count, replace=False))
    config = sim.scene.lod
    policy = LodPolicy(config, sim.scene.material, sim.scene.simulation.gravity)
    args = (sim.hierarchy, sim.elements, sim.vertex_ids, sim.triangle_ids, sim.positions,
            sim.velocities, sim.masses, 10.0, held)
    d0, d1 = _both(policy.decide, *args, lookahead=0.05)
    assert_lod_decisions_agree(d1, d0, policy, *args[:7], lookahead=0.05)
    assert d0.merge and d0.refine                  # both lists exercised
    assert not set(held.tolist()) & {int(sim.hierarchy.midpoint[e]) for e in d1.merge}


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_split_candidates_are_the_hierarchys(seed):
    """The compiled twin of Hierarchy48.split_vertices, on a refined hierarchy
    and after some of its merges (free pool slots, border diamonds)."""
    sim = _perturbed(seed, 0.0, 0.0)
    h = sim.hierarchy
    compiled.use(True)
    vertices, kids = h.split_vertices()
    twin = policy_kernels.split_candidates(h)
    _same(vertices, twin[0])
    _same(kids, twin[1])
    assert np.any(kids[:, 2] < 0) and np.any(kids[:, 2] >= 0)      # border and interior
    merged = copy.deepcopy(h)
    for m in vertices[::3]:          # disjoint diamonds: each merge stays valid
        merged.apply(Merge(tuple(int(i) for i in merged.vertex_edge[m])))
    vertices, kids = merged.split_vertices()
    twin = policy_kernels.split_candidates(merged)
    _same(vertices, twin[0])
    _same(kids, twin[1])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(0, 120),
       detail_count=st.integers(0, 30), threshold=st.sampled_from([0.0, 0.5, 2.0]))
def test_refine_order_is_the_reference(seed, count, detail_count, threshold):
    """Ties (rounded deviations), NaN, repeats, detail triangles and triangles
    at the maximum level."""
    rng = np.random.default_rng(seed)
    pool = 3 * count + 40
    deviation = np.round(rng.uniform(0.0, 3.0, count), 1)
    deviation[rng.random(count) < 0.05] = np.nan
    triangle_ids = np.sort(rng.choice(pool, min(pool, 2 * count + 5), replace=False))
    hinge_tris = rng.integers(0, len(triangle_ids), (count, 2))
    level = rng.integers(0, 4, pool)
    detail = rng.choice(pool, detail_count).astype(np.int64)
    max_level = 3
    # The reference: LodPolicy.decide's numpy lines.
    refine = []
    over = np.flatnonzero(deviation > threshold)
    order = over[np.argsort(-deviation[over], kind="stable")]
    if len(order) or len(detail):
        candidates = np.concatenate([triangle_ids[hinge_tris[order].ravel()], detail])
        candidates = candidates[level[candidates] < max_level]
        _, first = np.unique(candidates, return_index=True)
        refine = candidates[np.sort(first)].tolist()
    compiled.use(True)
    assert policy_kernels.refine_order(deviation, threshold, hinge_tris, triangle_ids, level,
                                       max_level, detail) == refine


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_merge_candidates_are_the_candidates_and_their_tests(seed):
    """The one-call twin (policy_kernels.merge_candidates) of split_candidates and
    mergeable, which LodPolicy.decide uses: the same arrays."""
    sim = _perturbed(seed, 0.02, 1e-4, half=True)
    h, config = sim.hierarchy, sim.scene.lod
    compiled.use(True)
    m, _ = lod_policy._criterion(sim.elements, 3e-5, sim.positions, sim.velocities)
    vertices, kids = h.split_vertices()
    held = vertices[::5]
    cutoff = float(np.median(h.birth[h.active_triangles()]))
    ok = policy_kernels.mergeable(sim.elements.hinge_vertices, m, config, sim.vertex_ids,
                                  vertices, kids, h.birth, cutoff, held, h.vertex_end)
    twin = policy_kernels.merge_candidates(h, sim.elements.hinge_vertices, m, config,
                                           sim.vertex_ids, cutoff, held)
    for a, b in zip((vertices, kids, ok), twin):
        _same(a, b)
    assert ok.any() and not ok.all()
    # An id the tests reject: no ok, as mergeable's None.
    assert policy_kernels.merge_candidates(h, sim.elements.hinge_vertices, m, config,
                                           sim.vertex_ids, cutoff, np.array([h.vertex_end]))[2] is None
    compiled.use(False)
    assert policy_kernels.merge_candidates(h, sim.elements.hinge_vertices, m, config,
                                           sim.vertex_ids, cutoff, held) is None
