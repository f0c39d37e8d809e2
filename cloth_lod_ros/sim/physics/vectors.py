"""Vector helpers of the force code: dot and cross products over the rows of
``(m, 3)`` arrays or the columns of component-major ``(3, m)`` ones (one
contiguous loop per component instead of m loops of length 3), and the
gather of triangle corners.  Pure arithmetic, no units of their own.
"""

from __future__ import annotations

import numpy as np


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def _dot_soa(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Column-wise dot product of ``(3, m)`` arrays."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _dot_soa_02(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`_dot_soa` summed as ``(a₀b₀ + a₂b₂) + a₁b₁``: the order in which
    ``np.einsum`` sums a length-3 axis (numpy 2.4, measured), so that the air's
    component-major terms equal the former ``(t, 3)`` einsum code bit for bit."""
    return (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]


def _cross_soa(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Column-wise cross product of ``(3, m)`` arrays (rows written in place)."""
    out = np.empty((3,) + a.shape[1:], dtype=np.result_type(a, b))
    np.subtract(a[1] * b[2], a[2] * b[1], out=out[0])
    np.subtract(a[2] * b[0], a[0] * b[2], out=out[1])
    np.subtract(a[0] * b[1], a[1] * b[0], out=out[2])
    return out


def _corners(elements, x: np.ndarray) -> np.ndarray:
    """Corner positions (or velocities) ``(3 corners, 3 components, t)`` of the
    triangles of ``elements`` (:class:`~cloth_lod_ros.sim.physics.elements.Elements`,
    its ``triangles_cm``) from ``x`` ``(n, 3)``: one gather from contiguous ``(3, n)`` data
    by the contiguous ``(3, t)`` index (gathering columns of the strided
    ``x.T`` with strided index columns cost several times more).  Pure copies."""
    return np.take(np.ascontiguousarray(x.T), elements.triangles_cm, axis=1).swapaxes(0, 1)
