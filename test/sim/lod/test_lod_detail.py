"""The detail criterion (issue 33): hinge and hierarchical details against closed forms,
relative thresholds, and accuracy that never drops when the maximum level rises."""

import numpy as np
import pytest

from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform
from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48
from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.physics.hinges_kernels import hinge_angles
from cloth_lod_ros.sim.lod.policy import (curvature_estimate, hinge_detail, relative_thresholds,
                                      vertex_detail)
from cloth_lod_ros.sim.scene.config import load_scene
from cloth_lod_ros.sim.mesh.sampling import material_grid, rms_and_max_distance
from cloth_lod_ros.sim import ClothSim


def uniform(level, blocks=(4, 4), size=1.0):
    mesh = refine_uniform(base_mesh(size, size, *blocks), level)
    return mesh, precompute(mesh)


def split_particles(level):
    """A hierarchy refined uniformly to ``level``: its uv ``(n, 2)`` (pool) and every
    split particle with its edge's ends, ``(k,)`` and ``(k, 2)`` pool ids."""
    base = base_mesh(1.0, 1.0, 4, 4)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(len(base.uv))]), 0.1, level)
    h.refine_uniform(level)
    ids = np.flatnonzero(h.vertex_active[:h.vertex_end] & (h.vertex_parents[:h.vertex_end, 0] >= 0))
    return h.uv[:h.vertex_end], ids, h.vertex_edge[ids]


@pytest.mark.parametrize("level", [0, 1, 3, 4])
def test_an_affine_field_has_no_detail(level):
    """A field affine in (u, v) is what linear triangles represent exactly."""
    rng = np.random.default_rng(level)
    mesh, el = uniform(level)
    a, b = rng.normal(size=(3, 2)), rng.normal(size=3)
    field = mesh.uv @ a.T + b
    scale = np.abs(field).max()
    assert np.abs(hinge_detail(mesh.uv, el.hinge_vertices, field)).max() < 1e-12 * scale
    uv, ids, ends = split_particles(level + 1)
    field = uv @ a.T + b
    assert vertex_detail(field, ids, ends).max() < 1e-12 * scale


def test_hierarchical_detail_of_a_quadratic_is_curvature_times_edge_squared_over_8():
    """z = κ (d·u)² / 2: the midpoint misses the chord by κ (d·ℓ)² / 8 on every edge ℓ."""
    kappa, d = 3.0, np.array([0.6, 0.8])
    for level in (1, 2, 5):
        uv, ids, ends = split_particles(level)
        field = np.column_stack([uv, 0.5 * kappa * (uv @ d) ** 2])
        edge = uv[ends[:, 1]] - uv[ends[:, 0]]
        np.testing.assert_allclose(vertex_detail(field, ids, ends), kappa * (edge @ d) ** 2 / 8,
                                   rtol=1e-9, atol=1e-15)


def test_hinge_detail_of_a_quadratic_falls_as_edge_squared():
    """The same quadratic on uniform levels l and l + 2 (similar meshes, legs
    halved): every hinge's detail is exactly a quarter, the largest ∝ κ h²."""
    kappa, d = 2.0, np.array([1.0, 0.0])
    peak = {}
    for level in (1, 2, 3, 4, 5):
        mesh, el = uniform(level)
        field = np.column_stack([mesh.uv, 0.5 * kappa * (mesh.uv @ d) ** 2])
        peak[level] = hinge_detail(mesh.uv, el.hinge_vertices, field).max()
    leg = {level: 0.25 * 2.0 ** (-level / 2) for level in peak}
    ratio = [peak[level] / (kappa * leg[level] ** 2) for level in peak]
    # Same parity: similar meshes, so the same constant exactly.
    assert ratio[0] == pytest.approx(ratio[2], rel=1e-9) == pytest.approx(ratio[4], rel=1e-9)
    assert ratio[1] == pytest.approx(ratio[3], rel=1e-9)
    assert ratio[0] > 0 and ratio[1] > 0


def test_hinge_detail_of_a_gentle_fold_is_the_papers_deviation():
    """An unstretched cloth rolled on a cylinder of radius R: to second order in
    the hinge angle, the position detail is the paper's d = (L/2) tan(θ/4)."""
    radius = 3.0
    mesh, el = uniform(4)
    u, v = mesh.uv[:, 0], mesh.uv[:, 1]
    x = np.column_stack([radius * np.sin(u / radius), v, radius * (1 - np.cos(u / radius))])
    theta, grad = hinge_angles(x, el.hinge_vertices, with_gradient=True)
    norms = np.linalg.norm(grad, axis=2)
    height = 0.5 * (1 / norms[:, 2] + 1 / norms[:, 3])
    paper = curvature_estimate(theta, height)
    ours = hinge_detail(mesh.uv, el.hinge_vertices, x)
    bent = paper > 1e-3 * paper.max()
    np.testing.assert_allclose(ours[bent], paper[bent], rtol=1e-3)
    # ... and it sees what the angle cannot: a velocity field the triangles miss.
    spin = np.column_stack([np.zeros_like(u), np.zeros_like(u), u * u])
    assert hinge_detail(mesh.uv, el.hinge_vertices, spin).max() > 0


def test_relative_thresholds_halve_with_each_level():
    """tolerance · h²/side: h² halves with each level of the 4-8 tree."""
    scene = load_scene("hang_two_corners", ["lod.tolerance=1.0"])
    refine = {}
    for level in (4, 5, 6, 7):
        cloth = scene.cloth.__class__(**{**scene.cloth.__dict__, "level": level})
        refine[level], coarsen = relative_thresholds(scene.lod, cloth)
        assert coarsen / refine[level] == pytest.approx(
            scene.lod.coarsen_threshold / scene.lod.refine_threshold)
    for level in (4, 5, 6):
        assert refine[level + 1] == pytest.approx(refine[level] / 2)
    # Level 6 of the 1 m, 4 x 4 cloth: a 1/32 m leg; 1 × h² / side.
    assert refine[6] == pytest.approx((1 / 32) ** 2)


def _final_positions(overrides, points, duration):
    sim = ClothSim(load_scene("hang_two_corners", overrides))
    sim.run(duration)
    return sim.sample(points)


def test_a_higher_maximum_level_is_never_less_accurate():
    """Against a finer uniform run (the converged mesh of these levels), the
    detail criterion at a fixed tolerance: max level L + 1 at least as accurate as L."""
    duration = 0.5
    points = material_grid(1.0, 1.0, 11)
    common = ["simulation.error_tolerance=0.0001"]
    reference = _final_positions(common + ["lod.enabled=false", "cloth.level=6"], points,
                                 duration)
    errors = []
    for level in (4, 5, 6):        # the curvature criterion: L6 0.0034 m against L5's 0.0027
        x = _final_positions(common + ["lod.criterion=detail", "lod.tolerance=1.0",
                                       f"cloth.level={level}"], points, duration)
        errors.append(rms_and_max_distance(x, reference)[0])
    assert errors[1] <= errors[0] and errors[2] <= errors[1], errors


def test_when_most_of_the_cloth_needs_the_finest_level_it_all_goes_there():
    """hang_two_corners at max level 4, tolerance 1: the criterion alone keeps
    58 % of the area at level 4 after 0.5 s.  With uniform_share 0.5 the mesh
    is made uniform there (the triangles of the uniform mesh, no more) and
    stays so while the criterion keeps most of it fine; with 1 (off) it is not."""
    base = ["lod.criterion=detail", "lod.tolerance=1.0", "cloth.level=4"]
    uniform = ClothSim(load_scene("hang_two_corners", ["lod.enabled=false", "cloth.level=4"]))
    shares = {}
    for share in (0.5, 1.0):
        sim = ClothSim(load_scene("hang_two_corners", base + [f"lod.uniform_share={share}"]))
        sim.run(0.5)
        levels = sim.hierarchy.level[sim.triangle_ids]
        area = 2.0 ** -levels
        shares[share] = (area[levels == 4].sum() / area.sum(), len(levels))
    assert shares[0.5] == (1.0, len(uniform.elements.triangles))
    assert 0.5 < shares[1.0][0] < 1.0
