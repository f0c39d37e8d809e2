"""Bending on adaptive meshes, against the uniform mesh at the finest level
(design §2, §4; issues 14 and 32).  With the squared-Hessian energy
(physics.bending, exact on quadratic surfaces on any mesh):

* a graded mesh holds the finest uniform mesh's bend energy on the same
  cylinder within 0.5 % (the hinge sum it replaced: up to 10 % less, and no
  weight for the hinges between levels fixed it);
* a split on a smooth bent surface changes its bend energy by O(h²) (the
  hinge sum doubled the split hinge's energy, ``½ k_b θ²``).
"""

from types import SimpleNamespace

import numpy as np
import pytest

from cloth_lod_ros.sim.physics.bending import bend_energy as stencil_energy, bend_stencils
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
    return stencil_energy(bend_stencils(mesh.uv, mesh.triangles), MATERIAL.bend_stiffness, x)


def graded(coarse: int, fine_region, finest: int = 6):
    """Level ``coarse`` everywhere, ``finest`` in ``fine_region`` (a predicate on a
    triangle's rest centroid) and along the border (so that the
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
def test_a_graded_mesh_holds_the_finest_meshes_bend_energy(layout, coarse):
    """Measured 0.9955–0.9990 of uniform level 6 on the same cylinder (the
    border refined to level 6 in both), every layout and axis direction."""
    mesh = graded(coarse, LAYOUTS[layout])
    finest = refine_uniform(BASE, 6)
    assert len(np.unique(mesh.levels)) >= 3                   # really graded
    for angle in ANGLES:
        ratio = bend_energy(mesh, cylinder(mesh.uv, angle)) / bend_energy(
            finest, cylinder(finest.uv, angle))
        assert ratio == pytest.approx(1.0, abs=0.006), (angle, ratio)


@pytest.mark.parametrize("level,bound", [(2, 2e-3), (3, 1e-3), (4, 4e-4)])
def test_a_split_on_a_cylinder_barely_changes_its_bend_energy(level, bound):
    """The new particle on the chord of a smooth bend: the stencils are exact
    on quadratics, so the energy moves by O(h²) of the surface's departure from
    one (measured −0.10 %, −0.067 %, −0.022 % at levels 2, 3, 4)."""
    h = Hierarchy48(BASE, np.zeros((BASE.vertex_count, 3)), 0.2, 8)
    h.refine_uniform(level)
    uv = h.uv[:h.vertex_end]
    h.x[:h.vertex_end] = cylinder(uv, 0.3)

    def energy():
        mesh, vids, _ = h.active_mesh()
        return bend_energy(mesh, h.x[vids])

    inner = [e for e in h._edges if len(h._edges[e]) == 2
             and all(h.hypotenuse(t) == e for t in h._edges[e])]
    edge = min(inner, key=lambda e: np.abs(uv[list(e)].mean(axis=0) - 0.5).sum())
    before = energy()
    h.apply(Split(edge))
    assert abs(energy() / before - 1.0) < bound
