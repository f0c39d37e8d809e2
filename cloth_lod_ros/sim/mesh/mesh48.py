"""4-8 bisection meshes of a rectangular cloth (paper §3, design §1, §4).

A 4-8 mesh starts from a grid of square *blocks*, each split by one diagonal into
two right isosceles triangles; the diagonals alternate like a chequerboard so that
interior vertices have valence 4 or 8 (paper Fig. 1).  Refining bisects a
triangle's hypotenuse at its midpoint and joins the midpoint to the opposite
vertex (paper Fig. 2).  Every triangle is therefore a right isosceles triangle in
the rest (u, v) plane, and the triangle produced by ``level`` bisections of a base
triangle has ``2**-level`` of its area.

Triangle storage convention used throughout the package: each row of
``triangles`` is ``(apex, left, right)``, counter-clockwise in (u, v), where
``left``-``right`` is the hypotenuse (the *refinement edge*) and ``apex`` is the
right-angle corner.  Bisecting it creates the midpoint ``m`` and the children
``(m, apex, left)`` and ``(m, right, apex)``, both again in that convention.

This module holds the *mechanism* on plain numpy arrays: construction, uniform
refinement, lumped masses and invariant checks (edges and hinges:
:mod:`.topology`).  It does not know about physics or level-of-detail policy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .topology import Hinges, MeshError, build_hinges
from .topology_kernels import build_hinges as compiled_hinges

__all__ = ["RestMesh", "base_mesh", "refine_uniform", "uniform_vertices_within",
           "triangle_rest_areas", "lumped_masses", "check_mesh"]


@dataclass
class RestMesh:
    """Topology and rest state of a 4-8 cloth mesh.

    Attributes:
        uv: ``(vertex_count, 2)`` rest material coordinates in metres.
        triangles: ``(triangle_count, 3)`` vertex indices ``(apex, left, right)``,
            counter-clockwise in (u, v); ``left``-``right`` is the hypotenuse.
        levels: ``(triangle_count,)`` bisection level of each triangle (0 = base).
        width, height: cloth size in metres (u spans [0, width], v [0, height]).
    """

    uv: np.ndarray
    triangles: np.ndarray
    levels: np.ndarray
    width: float
    height: float
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def vertex_count(self) -> int:
        return int(self.uv.shape[0])

    @property
    def triangle_count(self) -> int:
        return int(self.triangles.shape[0])

    def hinges(self) -> "Hinges":
        """Interior edges with their two opposite vertices (cached per topology)."""
        if "hinges" not in self._cache:
            # Compiled when numba is there (the same arrays).
            self._cache["hinges"] = compiled_hinges(self.triangles, self.vertex_count)
        return self._cache["hinges"]


def base_mesh(width: float, height: float, blocks_u: int, blocks_v: int) -> RestMesh:
    """Level-0 4-8 mesh: ``blocks_u`` x ``blocks_v`` square blocks, 2 triangles each.

    Args:
        width, height: cloth size in metres.  Blocks must be square, i.e.
            ``width / blocks_u == height / blocks_v``.
        blocks_u, blocks_v: number of blocks along u and v (>= 1).

    Returns:
        A mesh with ``(blocks_u + 1) * (blocks_v + 1)`` vertices and
        ``2 * blocks_u * blocks_v`` triangles (5x5 vertices and 32 triangles for
        the paper's 4x4 base).
    """
    if blocks_u < 1 or blocks_v < 1:
        raise MeshError("a base grid needs at least one block in each direction")
    side_u, side_v = width / blocks_u, height / blocks_v
    if not np.isclose(side_u, side_v, rtol=1e-12, atol=0.0):
        raise MeshError(
            f"base blocks must be square: width/blocks_u = {side_u} m but "
            f"height/blocks_v = {side_v} m")
    nu = blocks_u + 1
    iu, iv = np.meshgrid(np.arange(nu), np.arange(blocks_v + 1), indexing="xy")
    uv = np.column_stack([iu.ravel() * side_u, iv.ravel() * side_v])
    # Exact boundary values (no rounding drift at the far edges).
    uv[iu.ravel() == blocks_u, 0] = width
    uv[iv.ravel() == blocks_v, 1] = height

    bi, bj = np.meshgrid(np.arange(blocks_u), np.arange(blocks_v), indexing="xy")
    bi, bj = bi.ravel(), bj.ravel()
    p00 = bj * nu + bi
    p10, p01, p11 = p00 + 1, p00 + nu, p00 + nu + 1
    even = (bi + bj) % 2 == 0
    # Even blocks: diagonal p00-p11; odd blocks: diagonal p10-p01 (chequerboard).
    tri_a = np.where(even[:, None], np.column_stack([p10, p11, p00]),
                     np.column_stack([p00, p10, p01]))
    tri_b = np.where(even[:, None], np.column_stack([p01, p00, p11]),
                     np.column_stack([p11, p01, p10]))
    triangles = np.empty((2 * len(p00), 3), dtype=np.int64)
    triangles[0::2], triangles[1::2] = tri_a, tri_b
    return RestMesh(uv=uv, triangles=triangles,
                    levels=np.zeros(len(triangles), dtype=np.int64),
                    width=float(width), height=float(height))


def refine_uniform(mesh: RestMesh, levels: int) -> RestMesh:
    """Bisect every triangle ``levels`` times (vectorised; face rule only).

    Each pass adds one vertex at the midpoint of every hypotenuse (shared by the
    two triangles of a block, or alone on the boundary) and doubles the triangle
    count.  Level 6 of the 4x4-block base is the 33x33 grid.
    """
    uv, tris, lev = mesh.uv, mesh.triangles, mesh.levels
    for _ in range(int(levels)):
        apex, left, right = tris[:, 0], tris[:, 1], tris[:, 2]
        lo, hi = np.minimum(left, right), np.maximum(left, right)
        keys = lo * (len(uv) + 1) + hi
        unique_keys, first, inverse = np.unique(keys, return_index=True,
                                                return_inverse=True)
        midpoints = 0.5 * (uv[lo[first]] + uv[hi[first]])
        mid = len(uv) + inverse
        uv = np.vstack([uv, midpoints])
        child_a = np.column_stack([mid, apex, left])
        child_b = np.column_stack([mid, right, apex])
        new = np.empty((2 * len(tris), 3), dtype=np.int64)
        new[0::2], new[1::2] = child_a, child_b
        tris = new
        lev = np.repeat(lev + 1, 2)
    return RestMesh(uv=uv, triangles=tris, levels=lev,
                    width=mesh.width, height=mesh.height)


def uniform_vertices_within(width: float, height: float, block: float, level: int,
                            centre, radius: float) -> np.ndarray:
    """``(m, 2)`` rest (u, v) (m) of the vertices of the uniform level-``level`` mesh
    within ``radius`` (m) of ``centre`` ``(2,)`` (m), without building the mesh.

    At level 2p the vertices of a 4-8 mesh of square blocks of side ``block`` (m)
    are the lattice of spacing ``block / 2**p``; level 2p + 1 adds the centres of
    its cells (design §3, the multigrid's lattices).
    """
    step = block / 2 ** (level // 2)
    centre = np.asarray(centre, dtype=float)
    shifts = [(0.0, 0.0), (0.5, 0.5)] if level % 2 else [(0.0, 0.0)]
    out = []
    for du, dv in shifts:
        lo = np.floor((centre - radius) / step - (du, dv)) - 1
        hi = np.ceil((centre + radius) / step - (du, dv)) + 1
        i, j = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
        uv = np.column_stack([(i.ravel() + du) * step, (j.ravel() + dv) * step])
        keep = ((np.linalg.norm(uv - centre, axis=1) <= radius + 1e-12)
                & (uv[:, 0] >= 0) & (uv[:, 0] <= width + 1e-12)
                & (uv[:, 1] >= 0) & (uv[:, 1] <= height + 1e-12))
        out.append(uv[keep])
    return np.concatenate(out)


def triangle_rest_areas(uv: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Signed rest areas in m^2, ``(triangle_count,)``; positive when CCW."""
    p0, p1, p2 = uv[triangles[:, 0]], uv[triangles[:, 1]], uv[triangles[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def lumped_masses(uv: np.ndarray, triangles: np.ndarray, density: float,
                  vertex_count: int | None = None) -> np.ndarray:
    """Particle masses in kg: each triangle's ``area * density`` split in thirds (paper §5.5).

    Args:
        density: areal density in kg/m^2.
    Returns:
        ``(vertex_count,)`` masses; they sum to ``density * total area``.
    """
    n = len(uv) if vertex_count is None else vertex_count
    third = np.repeat(triangle_rest_areas(uv, triangles) * (density / 3.0), 3)
    return np.bincount(triangles.ravel(), weights=third, minlength=n)


def check_mesh(mesh: RestMesh, atol: float = 1e-12) -> None:
    """Assert the 4-8 invariants; raise :class:`MeshError` naming the first broken one.

    Checks: every triangle is a counter-clockwise right isosceles triangle whose
    right angle is at ``apex`` and whose area is ``2**-level`` of a base block
    triangle; the mesh is conforming (each interior edge has exactly two
    triangles, boundary edges lie on the rectangle's border, no vertex lies
    inside an edge); the triangles tile the rectangle exactly.
    """
    uv, t = mesh.uv, mesh.triangles
    apex, left, right = uv[t[:, 0]], uv[t[:, 1]], uv[t[:, 2]]
    a, b = left - apex, right - apex
    scale = max(mesh.width, mesh.height)
    if np.any(np.abs(np.einsum("ij,ij->i", a, b)) > atol * scale**2):
        raise MeshError("a triangle has no right angle at its apex")
    if np.any(np.abs(np.einsum("ij,ij->i", a, a) - np.einsum("ij,ij->i", b, b))
              > atol * scale**2):
        raise MeshError("a triangle is not isosceles")
    areas = triangle_rest_areas(uv, t)
    if np.any(areas <= 0):
        raise MeshError("a triangle is degenerate or clockwise in (u, v)")
    if len(mesh.levels) != len(t):
        raise MeshError("levels must give one bisection level per triangle")
    base_areas = areas * np.exp2(np.asarray(mesh.levels, dtype=float))
    if not np.allclose(base_areas, base_areas[0], rtol=1e-9, atol=0):
        raise MeshError("a triangle's area is not 2**-level of a base triangle")
    if not np.isclose(areas.sum(), mesh.width * mesh.height, rtol=1e-12, atol=0):
        raise MeshError(f"triangles cover {areas.sum()} m^2, cloth is "
                        f"{mesh.width * mesh.height} m^2")
    hinges = build_hinges(t, mesh.vertex_count)
    be = uv[hinges.boundary_edges]
    on_border = ((np.abs(be[..., 0]) <= atol * scale).all(1)
                 | (np.abs(be[..., 0] - mesh.width) <= atol * scale).all(1)
                 | (np.abs(be[..., 1]) <= atol * scale).all(1)
                 | (np.abs(be[..., 1] - mesh.height) <= atol * scale).all(1))
    if not on_border.all():
        raise MeshError("an edge inside the cloth has only one triangle (T-junction or hole)")
    used = np.zeros(mesh.vertex_count, dtype=bool)
    used[t.ravel()] = True
    if not used.all():
        raise MeshError("a vertex belongs to no triangle")
