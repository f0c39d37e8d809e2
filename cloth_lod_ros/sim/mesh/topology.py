"""Edges of a triangle mesh: its interior edges as bending hinges with their
opposite vertices, its border, and the errors of a mesh that is not a
consistently oriented manifold (design §1).  Compiled:
:mod:`.topology_kernels`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Hinges", "build_hinges", "MeshError"]


class MeshError(ValueError):
    """A mesh violates one of the 4-8 invariants."""


@dataclass(frozen=True)
class Hinges:
    """Interior edges of a triangle mesh, as bending hinges.

    Attributes:
        edge: ``(hinge_count, 2)`` vertex indices of the shared edge.
        opposite: ``(hinge_count, 2)`` the vertex opposite the edge in each of
            the two triangles: ``opposite[:, 0]`` lies in the triangle where the
            edge runs ``edge[:,0] -> edge[:,1]`` counter-clockwise.
        triangles: ``(hinge_count, 2)`` the two triangle indices, same order.
        is_hypotenuse: ``(hinge_count, 2)`` whether the edge is that triangle's
            hypotenuse.
        boundary_edges: ``(boundary_count, 2)`` edges with one triangle.
        edges: from the compiled build only (None from this module's), the
            edge structure the sparsity pattern is built from:
            ``(ends (e, 2), half_edge (3t,), corner (hinge_count, 2))``
            (:func:`cloth_lod_ros.sim.mesh.topology_kernels._hinges`).
    """

    edge: np.ndarray
    opposite: np.ndarray
    triangles: np.ndarray
    is_hypotenuse: np.ndarray
    boundary_edges: np.ndarray
    edges: tuple | None = None


def build_hinges(triangles: np.ndarray, vertex_count: int) -> Hinges:
    """Find interior edges and their two opposite vertices (vectorised).

    Raises:
        MeshError: if an edge is shared by more than two triangles or two
            triangles traverse a shared edge in the same direction
            (inconsistent orientation).
    """
    t = np.asarray(triangles, dtype=np.int64)
    # Half-edge 3i + k runs t[i,k] -> t[i,(k+1)%3]; its opposite is t[i,(k+2)%3].
    start = t.ravel()
    end = t[:, [1, 2, 0]].ravel()
    keys = np.minimum(start, end) * (vertex_count + 1) + np.maximum(start, end)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    # Groups of equal keys, read off the sorted keys (what np.unique with
    # return_index/return_counts gives, without its second sort).
    starts = np.empty(len(keys), dtype=bool)
    starts[:1] = True
    np.not_equal(sorted_keys[1:], sorted_keys[:-1], out=starts[1:])
    group_start = np.flatnonzero(starts)
    counts = np.diff(group_start, append=len(keys))
    if np.any(counts > 2):
        raise MeshError("non-manifold mesh: an edge is shared by more than two triangles")
    pair = counts == 2
    shared = group_start[pair]
    first, second = order[shared], order[shared + 1]
    if np.any(start[first] == start[second]):
        raise MeshError("inconsistent orientation: two triangles traverse an edge the same way")
    single = order[group_start[~pair]]
    # Triangle and corner of each side's half-edge, computed for the hinges
    # only; corner 0 is the apex, so half-edge 1 (left -> right) is the hypotenuse.
    tri_of, corner = np.divmod(np.column_stack([first, second]), 3)
    return Hinges(
        edge=np.column_stack([start[first], end[first]]),
        opposite=t[tri_of, (corner + 2) % 3],
        triangles=tri_of,
        is_hypotenuse=corner == 1,
        boundary_edges=np.column_stack([start[single], end[single]]),
    )
