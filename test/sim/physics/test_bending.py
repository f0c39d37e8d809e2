"""The squared-Hessian bending energy (physics.bending) against closed forms.

``E = k_b/2 ∫ |∇²x|² dA`` on the rest sheet: zero for every affine map (rigid
motions included, free edges too), ``k_b/2 κ² A`` for a cylinder and
``k_b c² A`` for a twist ``z = c u v`` (Poisson ratio 0), the same in every
direction of the material; and the smooth surface is the discrete energy's
minimum (the hinge sum it replaced let a zig-zag of the valence-8 particles
lower a bent sheet's energy by a quarter, issue 32).
"""

import functools
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform
from cloth_lod_ros.sim.physics.bending import bend_energy, bend_matrix, bend_stencils

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "lod"))
from test_bend_lod import LAYOUTS, graded  # noqa: E402  (its graded meshes)

KB = 2e-4           # N·m


@functools.lru_cache(maxsize=None)
def uniform(level, blocks=(2, 2), size=1.0):
    return refine_uniform(base_mesh(size, size, *blocks), level)


@functools.lru_cache(maxsize=1)
def meshes():
    return {"level 4": uniform(4), "level 5": uniform(5),
            "graded disc": graded(2, LAYOUTS["disc"]),
            "graded band": graded(3, LAYOUTS["diagonal band"])}


QUADRATICS = {   # q(u, v) and ∫|∇²q|² per unit area
    "cylinder along u": (lambda u, v: 0.5 * u**2, 1.0),
    "cylinder along v": (lambda u, v: 0.5 * v**2, 1.0),
    "cylinder at 45°": (lambda u, v: 0.25 * (u + v)**2, 1.0),
    "cylinder at 0.3 rad": (lambda u, v: 0.5 * (np.cos(0.3) * u + np.sin(0.3) * v)**2, 1.0),
    "twist": (lambda u, v: u * v, 2.0),
    "saddle": (lambda u, v: 0.5 * (u**2 - v**2), 2.0),
}


@pytest.mark.parametrize("name", ["level 4", "level 5", "graded disc", "graded band"])
def test_rigid_and_affine_maps_cost_nothing(name):
    mesh = meshes()[name]
    st = bend_stencils(mesh.uv, mesh.triangles)
    rng = np.random.default_rng(1)
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    flat = np.column_stack([mesh.uv, np.zeros(mesh.vertex_count)])
    curved = flat.copy()
    curved[:, 2] = 0.3 * mesh.uv[:, 0] ** 2
    reference = bend_energy(st, KB, curved)
    for x in (flat @ rotation.T + rng.normal(size=3),
              flat @ rng.normal(size=(3, 3)).T):                   # any affine map
        assert bend_energy(st, KB, x) < 1e-20 * reference
    q = bend_matrix(st, mesh.vertex_count)
    for d in range(3):       # Q annihilates affine coordinate functions: no force
        assert np.abs(q @ (flat @ rotation.T)[:, d]).max() < 1e-9 * np.abs(q @ curved[:, 2]).max()


@pytest.mark.parametrize("name", ["level 4", "level 5", "graded disc", "graded band"])
@pytest.mark.parametrize("shape", list(QUADRATICS))
def test_a_placed_quadratic_has_the_continuum_energy_on_any_mesh(name, shape):
    """Every stencil is exact on quadratics and their weights tile the sheet:
    ``k_b/2 ∫|∇²x|²`` exactly, in every direction (isotropy), uniform or graded."""
    mesh = meshes()[name]
    q, density = QUADRATICS[shape]
    x = np.column_stack([mesh.uv, q(mesh.uv[:, 0] - 0.5, mesh.uv[:, 1] - 0.5)])
    energy = bend_energy(bend_stencils(mesh.uv, mesh.triangles), KB, x)
    assert energy == pytest.approx(0.5 * KB * density * 1.0, rel=1e-10)


def relaxed_ratio(mesh, q, band=0.15):
    """The sheet's z held to q on a border band, the rest relaxed to the
    energy's minimum (small deflection: z only): its energy over q's."""
    uv = mesh.uv
    matrix = bend_matrix(bend_stencils(uv, mesh.triangles), mesh.vertex_count)
    z = q(uv[:, 0] - 0.5, uv[:, 1] - 0.5)
    held = (uv.min(axis=1) < band) | (uv.max(axis=1) > 1 - band)
    free, fixed = np.flatnonzero(~held), np.flatnonzero(held)
    relaxed = z.copy()
    relaxed[free] = spla.spsolve(matrix[free][:, free].tocsc(), -matrix[free][:, fixed] @ z[fixed])
    return (relaxed @ (matrix @ relaxed)) / (z @ (matrix @ z)), np.abs(relaxed - z).max()


@pytest.mark.parametrize("level", [6, 7])
@pytest.mark.parametrize("shape", list(QUADRATICS))
def test_the_smooth_surface_is_the_minimum_on_a_uniform_mesh(level, shape):
    """Held on a border band, the interior relaxes onto the quadratic itself:
    the stencils' sums telescope (no zig-zag mode lowers the energy)."""
    ratio, deviation = relaxed_ratio(uniform(level), QUADRATICS[shape][0])
    assert deviation < 1e-12
    assert ratio == pytest.approx(1.0, abs=1e-10)


@pytest.mark.parametrize("layout", list(LAYOUTS))
@pytest.mark.parametrize("coarse", [2, 3])
def test_a_graded_mesh_relaxes_at_most_a_few_percent_below_the_surface(layout, coarse):
    """Measured: relaxed/placed 0.981–0.998 for cylinders (any direction) and
    0.953–0.998 for the twist, the difference at the transitions between
    levels (stencils fitted where the lattice's are missing); the hinge sum
    it replaced relaxed to ~0.7 on every mesh."""
    mesh = graded(coarse, LAYOUTS[layout]) if (coarse, layout) not in (
        (2, "disc"), (3, "diagonal band")) else meshes()[f"graded {layout.split()[-1]}"]
    for name, (q, _) in QUADRATICS.items():
        ratio, _ = relaxed_ratio(mesh, q)
        floor = 0.95 if name in ("twist", "saddle") else 0.98
        assert floor <= ratio <= 1.0 + 1e-10, name
