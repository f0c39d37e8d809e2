"""Per-element rest data of one mesh topology: triangle areas, the
deformation-gradient maps and the bend weights of the hinges (BW §4.2,
design §2).  Recomputed at every topology change (compiled:
:mod:`.elements_kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..mesh.mesh48 import RestMesh
from .bending import BendStencils, bend_stencils

__all__ = ["Elements", "precompute", "triangle_maps", "hinge_weights"]


@dataclass(frozen=True)
class Elements:
    """Per-element rest data for one mesh topology (recomputed on topology change).

    Attributes:
        triangles: ``(t, 3)`` vertex indices.
        area: ``(t,)`` rest areas, m².
        coef_u, coef_v: ``(t, 3)`` coefficients (1/m) with
            ``w_u = Σ_k coef_u[k] x_k`` and ``w_v = Σ_k coef_v[k] x_k``.
        hinge_vertices: ``(h, 4)`` ``(e0, e1, o0, o1)``: shared edge, opposite vertices.
        hinge_weight: ``(h,)`` dimensionless ``c_e`` (see module docstring).
        hinge_triangles: ``(h, 2)`` the two triangles of each hinge.
        vertex_count: number of vertices.
        edges: edge structure for the sparsity pattern, or None (topology.Hinges.edges).
        rest_uv: ``(n, 2)`` rest material coordinates, m (the bending stencils'
            geometry; None: no bending).
        bend: the :class:`~.bending.BendStencils` of this topology (made from
            ``rest_uv``, ``triangles`` and ``clamped`` when first read).
        clamped: ``(n,)`` bool, the particles held rigidly (pin and grasp
            patches): the bending energy is the free sheet's, clamped there
            (:func:`~.bending.bend_stencils`); None: nothing held.
        coef_u_cm, coef_v_cm, triangles_cm: ``(3, t)`` contiguous transposes of
            ``coef_u``, ``coef_v``, ``triangles`` (the component-major code reads rows).
    """

    triangles: np.ndarray
    area: np.ndarray
    coef_u: np.ndarray
    coef_v: np.ndarray
    hinge_vertices: np.ndarray
    hinge_weight: np.ndarray
    hinge_triangles: np.ndarray
    vertex_count: int
    edges: tuple | None = field(default=None, repr=False)
    rest_uv: np.ndarray | None = field(default=None, repr=False)
    clamped: np.ndarray | None = field(default=None, repr=False)

    # Made when first read (only the numpy evaluation reads them), once per topology.
    coef_u_cm = cached_property(lambda self: np.ascontiguousarray(self.coef_u.T))
    coef_v_cm = cached_property(lambda self: np.ascontiguousarray(self.coef_v.T))
    triangles_cm = cached_property(lambda self: np.ascontiguousarray(self.triangles.T))

    @property
    def element_vertices(self) -> list:
        """The vertex lists of every element kind the system matrix couples:
        ``[triangles (t, 3), *bend stencils (s, k)]`` (the sparsity pattern's,
        :class:`~cloth_lod_ros.sim.solve.pattern.SparsePattern`)."""
        return [self.triangles, *(vertices for vertices, _ in self.bend.kinds)]

    @cached_property
    def bend(self) -> BendStencils:
        if self.rest_uv is None:
            return BendStencils(kinds=())
        return bend_stencils(self.rest_uv, self.triangles, self.clamped)


def precompute(mesh: RestMesh) -> Elements:
    """Rest-state coefficients of every triangle and hinge of ``mesh``.

    With rest differences ``Δu_k = u_k − u_0``, ``Δv_k = v_k − v_0`` the map
    ``[w_u w_v] = [Δx_1 Δx_2] [[Δu_1 Δu_2], [Δv_1 Δv_2]]⁻¹`` (BW §4.2) is linear
    in the three positions; its coefficients are stored once per topology.
    """
    uv, tri = mesh.uv, mesh.triangles
    area, coef_u, coef_v = triangle_maps(uv[tri])
    hinges = mesh.hinges()
    edge_vec = uv[hinges.edge[:, 1]] - uv[hinges.edge[:, 0]]
    weight = hinge_weights(np.einsum("ij,ij->i", edge_vec, edge_vec),
                           area[hinges.triangles], hinges.is_hypotenuse)
    return Elements(
        triangles=tri.copy(), area=area, coef_u=coef_u, coef_v=coef_v,
        hinge_vertices=np.column_stack([hinges.edge, hinges.opposite]),
        hinge_weight=weight, hinge_triangles=hinges.triangles,
        vertex_count=mesh.vertex_count, rest_uv=uv)


def triangle_maps(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest area and deformation-gradient coefficients of triangles (BW §4.2).

    Args:
        corners: ``(t, 3, 2)`` rest (u, v) of each triangle's corners, m.

    Returns:
        ``area`` ``(t,)`` in m² and ``coef_u``, ``coef_v`` ``(t, 3)`` in 1/m, with
        ``w_u = Σ_k coef_u[k] x_k`` (see :class:`Elements`).
    """
    d1 = corners[:, 1] - corners[:, 0]
    d2 = corners[:, 2] - corners[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    a1, a2 = d2[:, 1] / det, -d1[:, 1] / det
    b1, b2 = -d2[:, 0] / det, d1[:, 0] / det
    coef_u = np.column_stack([-(a1 + a2), a1, a2])
    coef_v = np.column_stack([-(b1 + b2), b1, b2])
    return 0.5 * det, coef_u, coef_v


def hinge_weights(edge_length2: np.ndarray, areas: np.ndarray,
                  hypotenuse: np.ndarray) -> np.ndarray:
    """Bend weights ``c_e = γ |e|² / (A₁ + A₂)`` (design §2), dimensionless, ``(h,)``.

    Args:
        edge_length2: ``(h,)`` rest ``|e|²``, m².
        areas: ``(h, 2)`` rest areas of the two triangles, m².
        hypotenuse: ``(h, 2)`` whether the edge is that triangle's hypotenuse
            (γ = ½ on such a side, 1 on a leg side, averaged over both).
    """
    # Written out over the two sides: the mean of two of {½, 1} is exact either
    # way, and a length-2 sum is the one addition; numpy's reductions along a
    # length-2 axis cost ~10x more than these column operations.
    hyp_count = hypotenuse[:, 0].astype(float) + hypotenuse[:, 1]
    gamma = 1.0 - 0.25 * hyp_count
    return gamma * edge_length2 / (areas[:, 0] + areas[:, 1])
