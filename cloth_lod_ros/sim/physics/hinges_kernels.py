"""Compiled (numba) hinge angles and their gradients, bitwise those of
:func:`cloth_lod_ros.sim.physics.hinges.hinge_angles` (Bridson et al. 2003).

:func:`_hinge_geometry` is one hinge's angle and gradient, in the numpy
code's operations and order; the bend forces (:mod:`.forces_kernels`) and the
LOD criterion (:mod:`cloth_lod_ros.sim.lod.policy_kernels`) call it per hinge.
Units: positions m, angles rad, gradients 1/m.
"""

from __future__ import annotations

import numpy as np

from ..runtime.compiled import _as_index, _jit, enabled
from . import hinges as _hinges

__all__ = ["hinge_angles"]


@_jit
def _hinge_geometry(x, a0, a1, b0, b1, g):
    """θ (rad) of hinge ``(a0, a1, b0, b1)`` (edge, then the opposite vertices) at
    positions x ``(n, 3)`` m, and ``∂θ/∂x`` into ``g`` ``(12,)`` 1/m: the
    operations of hinges.hinge_angles, in its order (Bridson et al. 2003)."""
    ex = x[a1, 0] - x[a0, 0]
    ey = x[a1, 1] - x[a0, 1]
    ez = x[a1, 2] - x[a0, 2]
    px = x[b0, 0] - x[a0, 0]
    py = x[b0, 1] - x[a0, 1]
    pz = x[b0, 2] - x[a0, 2]
    qx = x[b1, 0] - x[a0, 0]
    qy = x[b1, 1] - x[a0, 1]
    qz = x[b1, 2] - x[a0, 2]
    edge_len2 = ex * ex + ey * ey + ez * ez
    edge_len = np.sqrt(edge_len2)
    # n0 = edge × to_o0, n1 = to_o1 × edge.
    n0x = ey * pz - ez * py
    n0y = ez * px - ex * pz
    n0z = ex * py - ey * px
    n1x = qy * ez - qz * ey
    n1y = qz * ex - qx * ez
    n1z = qx * ey - qy * ex
    n0_len2 = n0x * n0x + n0y * n0y + n0z * n0z
    n1_len2 = n1x * n1x + n1y * n1y + n1z * n1z
    r0 = np.sqrt(n0_len2)
    r1 = np.sqrt(n1_len2)
    h0x, h0y, h0z = n0x / r0, n0y / r0, n0z / r0
    h1x, h1y, h1z = n1x / r1, n1y / r1, n1z / r1
    sx = h0y * h1z - h0z * h1y
    sy = h0z * h1x - h0x * h1z
    sz = h0x * h1y - h0y * h1x
    sin_t = (sx * ex + sy * ey + sz * ez) / edge_len
    cos_t = h0x * h1x + h0y * h1y + h0z * h1z
    th = np.arctan2(sin_t, cos_t)
    f0 = -(edge_len / n0_len2)
    f1 = -(edge_len / n1_len2)
    g[6], g[7], g[8] = f0 * n0x, f0 * n0y, f0 * n0z
    g[9], g[10], g[11] = f1 * n1x, f1 * n1y, f1 * n1z
    t0 = (px * ex + py * ey + pz * ez) / edge_len2
    t1 = (qx * ex + qy * ey + qz * ez) / edge_len2
    for d in range(3):
        g[d] = -((1 - t0) * g[6 + d] + (1 - t1) * g[9 + d])
        g[3 + d] = -(t0 * g[6 + d] + t1 * g[9 + d])
    return th


@_jit
def _angles(hv, x, theta, grad, with_gradient):
    """θ ``(h,)`` rad and, if ``with_gradient``, ∂θ/∂x ``(h, 4, 3)`` 1/m of the
    hinges ``hv`` ``(h, 4)`` at positions x ``(n, 3)`` m (hinges.hinge_angles)."""
    g = np.empty(12)
    for h in range(hv.shape[0]):
        theta[h] = _hinge_geometry(x, hv[h, 0], hv[h, 1], hv[h, 2], hv[h, 3], g)
        if with_gradient:
            for k in range(4):
                for d in range(3):
                    grad[h, k, d] = g[3 * k + d]


def hinge_angles(x: np.ndarray, hinge_vertices: np.ndarray, with_gradient: bool = False):
    """:func:`cloth_lod_ros.sim.physics.hinges.hinge_angles` (θ ``(h,)`` rad, optionally
    ∂θ/∂x ``(h, 4, 3)`` 1/m) by the compiled kernel when :func:`enabled`:
    bitwise the same numbers."""
    if not enabled():
        return _hinges.hinge_angles(x, hinge_vertices, with_gradient)
    hv = _as_index(hinge_vertices).reshape(-1, 4)
    theta = np.empty(len(hv))
    grad = np.empty((len(hv), 4, 3) if with_gradient else (0, 4, 3))
    _angles(hv, np.ascontiguousarray(x, dtype=np.float64), theta, grad, with_gradient)
    return (theta, grad) if with_gradient else theta
