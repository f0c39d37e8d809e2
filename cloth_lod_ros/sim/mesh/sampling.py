"""Sampling a cloth at material points, and distances between two cloths.

``sample(uv)`` evaluates the surface at arbitrary material coordinates by
barycentric interpolation in the rest triangle that contains each point
(design §5), which lets meshes of different resolution be compared at the
same material points.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["PointLocator", "rms_and_max_distance", "material_grid"]


class PointLocator:
    """Finds, for material points, the containing rest triangle and barycentrics.

    Candidate triangles come from a k-d tree over rest centroids; a point that
    none of its candidates contains (possible near strongly graded regions)
    falls back to a vectorised test against all triangles, so the answer is
    always exact.

    Args:
        uv: ``(n, 2)`` rest coordinates, m.
        triangles: ``(t, 3)`` vertex indices.
        width, height: cloth size, m (queries outside are refused).
    """

    def __init__(self, uv: np.ndarray, triangles: np.ndarray, width: float,
                 height: float, candidates: int = 12):
        self.uv, self.triangles = uv, triangles
        self.width, self.height = width, height
        corners = uv[triangles]                          # (t, 3, 2)
        self._origin = corners[:, 0]
        e1 = corners[:, 1] - corners[:, 0]
        e2 = corners[:, 2] - corners[:, 0]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        # Inverse of [e1 e2] per triangle, to get barycentrics with one product.
        self._inverse = np.stack([np.stack([e2[:, 1], -e2[:, 0]], -1),
                                  np.stack([-e1[:, 1], e1[:, 0]], -1)], 1) / det[:, None, None]
        self._tree = cKDTree(corners.mean(axis=1))
        self._k = min(candidates, len(triangles))
        self._tol = 1e-9 * max(width, height)
        self._last_query = None

    def _barycentric(self, points: np.ndarray, tri: np.ndarray) -> np.ndarray:
        local = np.einsum("...ab,...b->...a", self._inverse[tri], points - self._origin[tri])
        return np.concatenate([1.0 - local.sum(-1, keepdims=True), local], -1)

    def locate(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(triangle (m,), barycentric (m, 3))`` for ``(m, 2)`` points.

        Raises:
            ValueError: a point is not finite or lies outside the cloth.
        """
        points = np.atleast_2d(np.asarray(points, dtype=float))
        if points.shape[-1] != 2:
            raise ValueError(f"material points must have shape (m, 2), got {points.shape}")
        if not np.all(np.isfinite(points)):
            raise ValueError("material points must be finite")
        outside = ((points[:, 0] < -self._tol) | (points[:, 0] > self.width + self._tol)
                   | (points[:, 1] < -self._tol) | (points[:, 1] > self.height + self._tol))
        if outside.any():
            raise ValueError(f"material point {points[outside][0].tolist()} lies outside "
                             f"the {self.width} x {self.height} m cloth")
        _, cand = self._tree.query(points, k=self._k)
        cand = cand.reshape(len(points), -1)
        bary = self._barycentric(points[:, None, :], cand)       # (m, k, 3)
        worst = bary.min(axis=-1)
        best = worst.argmax(axis=1)
        rows = np.arange(len(points))
        tri = cand[rows, best]
        found_bary = bary[rows, best]
        missing = worst[rows, best] < -1e-9
        for i in np.flatnonzero(missing):        # rare: exhaustive but vectorised per point
            all_bary = self._barycentric(points[i][None, :], np.arange(len(self.triangles)))
            j = int(all_bary.min(axis=-1).argmax())
            tri[i], found_bary[i] = j, all_bary[j]
        return tri, found_bary

    def sample(self, positions: np.ndarray, points) -> np.ndarray:
        """3-D positions ``(m, 3)`` of material points on a cloth at ``positions``.

        The last query's triangles and barycentrics are kept: the same points
        are sampled at every published frame (``cloth/grid``), and the rest
        mesh - so where they lie - changes only with the topology, when a new
        locator is made."""
        points = np.asarray(points, dtype=float)
        kept = self._last_query
        if kept is not None and kept[0].shape == points.shape and np.array_equal(kept[0],
                                                                                 points):
            tri, bary = kept[1], kept[2]
        else:
            tri, bary = self.locate(points)
            self._last_query = (points.copy(), tri, bary)
        return np.einsum("mk,mkd->md", bary, positions[self.triangles[tri]])


def rms_and_max_distance(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """RMS and maximum of ``|a_i − b_i|`` over ``(m, 3)`` point sets, in m."""
    dist = np.linalg.norm(np.asarray(a) - np.asarray(b), axis=1)
    return float(np.sqrt(np.mean(dist**2))), float(dist.max())


def material_grid(width: float, height: float, resolution: int) -> np.ndarray:
    """``(resolution², 2)`` material points (m) evenly covering a ``width × height``
    cloth, row-major in v then u (the layout of ``cloth/grid``): the fixed
    sample points at which runs and recordings are compared."""
    us = np.linspace(0.0, width, resolution)
    vs = np.linspace(0.0, height, resolution)
    return np.stack(np.meshgrid(us, vs), axis=-1).reshape(-1, 2)
