"""Bending on adaptive meshes, against the uniform mesh at the finest level
(design §2, §4; issue 14 item 4).  Measured and documented, not corrected:

* a graded mesh bends up to ~10 % more softly than the uniform finest mesh on
  the same surface; the shortfall is at the hinges between levels, and no
  single weight for those hinges removes it for every layout and direction;
* a split adds exactly ``½ k_b θ²`` to the bend energy of a hinge of angle θ
  (that hinge's energy doubles), and no position of the new particle undoes
  it at an acceptable stretch cost.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import minimize

from cloth_lod_ros.sim.physics.energies import elastic_energies
from cloth_lod_ros.sim.physics.hinges import hinge_angles
from cloth_lod_ros.sim.physics.elements import precompute
from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48
from cloth_lod_ros.sim.mesh.operations import Split
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform

MATERIAL = SimpleNamespace(stretch_stiffness=2000.0, shear_stiffness=200.0, bend_stiffness=2e-4)
BASE = base_mesh(1.0, 1.0, 4, 4)
RADIUS = 0.5


def cylinder(uv: np.ndarray, angle: float) -> np.ndarray:
    """The sheet wrapped isometrically on a cylinder of radius 0.5 m whose axis lies
    at ``angle`` rad from v (bending along the direction at ``angle`` from u)."""
    along = np.array([np.cos(angle), np.sin(angle)])
    across = np.array([-along[1], along[0]])
    s, t = uv @ along, uv @ across
    flat = (RADIUS * np.sin(s / RADIUS))[:, None] * along + t[:, None] * across
    return np.column_stack([flat, RADIUS * (1 - np.cos(s / RADIUS))])


def bend_energy(mesh, x) -> float:
    elements = precompute(mesh)
    theta = hinge_angles(x, elements.hinge_vertices)
    return 0.5 * MATERIAL.bend_stiffness * float(np.sum(elements.hinge_weight * theta**2))


def graded(coarse: int, fine_region, finest: int = 6):
    """Level ``coarse`` everywhere, ``finest`` in ``fine_region`` (a predicate on a
    triangle's rest centroid) and along the border (so that the hingeless
    border strip is the uniform mesh's), graded by forced splits between."""
    h = Hierarchy48(BASE, np.zeros((BASE.vertex_count, 3)), 0.2, finest)
    h.refine_uniform(coarse)
    for _ in range(2 * finest):
        for t in h.active_triangles():
            corners = h.uv[h.tri[t]]
            if h.tri_active[t] and (fine_region(corners.mean(axis=0))
                                    or corners.min() < 1e-12 or corners.max() > 1 - 1e-12):
                h.refine(int(t))
    return h.active_mesh()[0]


ANGLES = (0.0, 0.3, np.pi / 4, np.pi / 2)
LAYOUTS = {
    "disc": lambda c: np.hypot(*(c - 0.5)) < 0.2,
    "diagonal band": lambda c: abs(c[0] - c[1]) < 0.1,
    "half": lambda c: c[0] < 0.5,
}


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("coarse", [2, 3])
def test_a_graded_mesh_bends_up_to_a_tenth_more_softly_than_the_finest(layout, coarse):
    """Measured: 0.2–9.8 % less bend energy than uniform level 6 on the same
    cylinder (the border refined to level 6 in both), depending on layout and
    axis direction; never more.  A uniform mesh's interior is exact at every
    level, so the shortfall is at the hinges between levels."""
    mesh = graded(coarse, LAYOUTS[layout])
    finest = refine_uniform(BASE, 6)
    assert len(np.unique(mesh.levels)) >= 3                   # really graded
    for angle in ANGLES:
        ratio = bend_energy(mesh, cylinder(mesh.uv, angle)) / bend_energy(
            finest, cylinder(finest.uv, angle))
        assert 0.88 < ratio <= 1.0 + 1e-9, (angle, ratio)


def test_no_one_weight_between_levels_makes_every_graded_mesh_exact():
    """The weight c* that the hinges between levels would need for the graded
    mesh to match the finest one (the others keep c_e = 1) ranges from 1.0 to
    1.5 over layouts and directions, so a weight correction fitted to one case
    is wrong for another (a constant 1.15 would leave −7 % to +1.3 %)."""
    finest = refine_uniform(BASE, 6)
    needed = []
    for region in LAYOUTS.values():
        mesh = graded(2, region)
        elements = precompute(mesh)
        levels = mesh.levels[elements.hinge_triangles]
        mixed = levels[:, 0] != levels[:, 1]
        for angle in ANGLES:
            theta2 = hinge_angles(cylinder(mesh.uv, angle), elements.hinge_vertices)**2
            target = 2 * bend_energy(finest, cylinder(finest.uv, angle)) / MATERIAL.bend_stiffness
            needed.append((target - theta2[~mixed].sum()) / theta2[mixed].sum())
    assert 1.0 <= min(needed) and max(needed) < 1.6
    assert max(needed) - min(needed) > 0.3


@pytest.mark.parametrize("level", [2, 4])
def test_a_uniform_interior_bends_exactly(level):
    """The comparison above is against an exact interior: on a uniform mesh the
    hinges away from the border carry k_b/2 R⁻² per area within 0.6 % (the
    centre's hinges are counted whole, so this is a sampling bound)."""
    mesh = refine_uniform(BASE, level)
    elements = precompute(mesh)
    for angle in (0.0, 0.3, np.pi / 4):
        theta = hinge_angles(cylinder(mesh.uv, angle), elements.hinge_vertices)
        per_triangle = np.bincount(elements.hinge_triangles.ravel(), minlength=mesh.triangle_count,
                                   weights=np.repeat(0.25 * MATERIAL.bend_stiffness * theta**2, 2))
        inner = np.all(np.abs(mesh.uv[mesh.triangles].mean(axis=1) - 0.5) < 0.25, axis=1)
        density = per_triangle[inner].sum() / elements.area[inner].sum()
        assert density == pytest.approx(0.5 * MATERIAL.bend_stiffness / RADIUS**2, rel=6e-3)


def folded(level: int, theta: float):
    """A uniform level-``level`` hierarchy folded by ``theta`` rad along the diagonal
    u = v, and the hypotenuse on the fold nearest the centre."""
    h = Hierarchy48(BASE, np.zeros((BASE.vertex_count, 3)), 0.2, 8)
    h.refine_uniform(level)
    uv = h.uv[:h.vertex_end]
    along, across = np.array([1.0, 1.0]) / np.sqrt(2), np.array([1.0, -1.0]) / np.sqrt(2)
    s = uv @ across
    side = s > 0
    x = np.column_stack([uv, np.zeros(len(uv))])
    x[side] = np.column_stack([(uv[side] @ along)[:, None] * along
                               + (s[side] * np.cos(theta))[:, None] * across,
                               s[side] * np.sin(theta)])
    h.x[:h.vertex_end] = x
    on_fold = [e for e in h._edges if len(h._edges[e]) == 2
               and all(h.hypotenuse(t) == e for t in h._edges[e])
               and np.all(np.abs(uv[list(e)] @ across) < 1e-12)]
    edge = min(on_fold, key=lambda e: abs(uv[list(e)].mean() - 0.5))
    return h, edge


def energies(h) -> dict:
    mesh, vids, _ = h.active_mesh()
    return elastic_energies(precompute(mesh), MATERIAL, h.x[vids])


@pytest.mark.parametrize("level,theta", [(2, 0.1), (2, 1.0), (4, 0.3)])
def test_a_split_across_a_fold_doubles_that_hinges_bend_energy(level, theta):
    """The new particle goes on the chord, so both halves of the split edge keep
    the fold angle θ, each with the whole edge's weight (c_e = 1): the split adds
    exactly ½ k_b θ² of bending and changes nothing else."""
    h, edge = folded(level, theta)
    before = energies(h)
    h.apply(Split(edge))
    after = energies(h)
    assert after["bend"] - before["bend"] == pytest.approx(
        0.5 * MATERIAL.bend_stiffness * theta**2, rel=1e-9)
    for key in ("stretch", "shear"):
        assert after[key] == pytest.approx(before[key], abs=1e-15)


@pytest.mark.parametrize("level,theta", [(2, 0.3), (4, 0.1)])
def test_no_position_of_the_new_particle_undoes_the_doubling(level, theta):
    """Placed anywhere (only existing particles may not move), the new particle
    still adds at least 85 % of ½ k_b θ² (measured 86–99.6 %): taking the fold off
    the split edge stretches the children (k_s/k_b = 10⁷ m⁻²) far more than it
    saves in bending.  A curved placement from the normals does not help either:
    for a fold along the edge the normals at its ends are parallel, so it is
    the chord."""
    h, edge = folded(level, theta)
    start = sum(energies(h)[k] for k in ("stretch", "shear", "bend"))
    h.apply(Split(edge))
    m = h.midpoint[edge]
    chord = h.x[m].copy()

    def added(offset):
        h.x[m] = chord + offset
        return sum(energies(h)[k] for k in ("stretch", "shear", "bend")) - start

    best = minimize(added, np.zeros(3), method="BFGS", options={"gtol": 1e-14})
    doubling = 0.5 * MATERIAL.bend_stiffness * theta**2
    assert added(np.zeros(3)) == pytest.approx(doubling, rel=1e-9)
    assert 0.85 * doubling < best.fun <= doubling
