"""Compiled (numba) kernels for the force evaluation and the sparse assembly.

The numpy code in :mod:`~cloth_lod_ros.sim.forces` and
:meth:`~cloth_lod_ros.sim.linear.SparsePattern.assemble` is the reference
implementation; this module computes the same quantities with one compiled
loop per element kind (triangles, hinges) instead of dozens of numpy passes
over ``(3, t)`` temporaries.  The maths is exactly the reference's (BW §4.2–4.5
conditions, forces, damping and the kept Jacobians of forces.py's docstring;
Bridson et al. 2003 for the hinge gradient), written per element.  Units are
SI: positions m, velocities m/s, forces N, stiffness blocks N/m times the
weights.

Besides the evaluation (:func:`evaluate`, :func:`assemble`), the per-step
measures have compiled twins: :func:`hinge_angles` (the LOD criterion, merge
energies), :func:`stretch_lengths` (the step's strain test) and
:func:`elastic_energies` (the statistics).

Selection: these functions use the kernels when numba
imports and the environment variable ``CLOTH_LOD_KERNELS`` is not ``numpy``
(``numba``/``auto``/unset: compiled if available); :func:`use` switches at run
time (tests, benchmarks).  Without numba everything falls back to the numpy
reference, which stays the definition.

The kernels are compiled on first use and cached next to this module
(``cache=True``: ``__pycache__/kernels.*.nbi``/``.nbc``), so a later process
only loads them.  ``error_model="numpy"``: a degenerate element (a zero-length
edge or normal) gives inf/nan like the numpy code instead of raising.
"""

from __future__ import annotations

import os

import numpy as np

from . import forces as _forces

try:
    import numba
except ImportError:                 # pragma: no cover - exercised without numba
    numba = None

__all__ = ["available", "enabled", "use", "evaluate", "assemble", "hinge_angles",
           "stretch_lengths", "elastic_energies"]

#: Whether numba imported (the compiled path can be used at all).
available = numba is not None
_enabled = available and os.environ.get("CLOTH_LOD_KERNELS", "auto").lower() != "numpy"


def enabled() -> bool:
    """Whether :func:`evaluate` and :func:`assemble` run the compiled kernels."""
    return _enabled


def use(compiled: bool) -> bool:
    """Select the compiled kernels (True, if numba is available) or the numpy
    reference (False); returns the previous setting."""
    global _enabled
    previous, _enabled = _enabled, bool(compiled) and available
    return previous


if available:
    _jit = numba.njit(cache=True, error_model="numpy", nogil=True)
else:                               # pragma: no cover
    def _jit(function):
        return function


@_jit
def _membrane(tri, cu, cv, area, x, v, ks, ksh, bs, bsh, c_k, c_d, air_coef, wind,
              force, kv, air_force, conditions, blocks, slots, data, mode):
    """Stretch + shear (+ air) of every triangle (BW §4.2, §4.5; design §2).

    Args:
        tri ``(t, 3)`` int64; cu, cv ``(t, 3)`` 1/m; area ``(t,)`` m²; x, v
        ``(n, 3)`` m, m/s; ks, ksh N/m; bs, bsh s; c_k, c_d the block weights
        (``γh²``, ``γh``); air_coef ``½ ρ C_d`` kg/m³ (0: no air); wind ``(3,)``
        m/s.
        force, kv, air_force: ``(n, 3)`` zeroed outputs: the membrane force (N),
            ``(∂f/∂x) v`` (N/s) and the air's face force (N), each summed in
            (triangle, corner) order like the reference's ``np.bincount``.
        conditions: ``(5, t)`` output ``C_u, C_v, C_s`` (m) and ``|w_u|, |w_v|``.
        blocks: ``(t, 81)`` output in the layout ``[e, i, a, j, b]`` of
            ``Evaluation.triangle_blocks`` (mode 1).
        slots, data: ``(t, 3, 3)`` the flat BSR data index of entry (0, 0) of
            each corner pair's block (SparsePattern.block_slots) and the flat
            data to add the blocks into (mode 2).  Adding in element order
            gives every entry the same sum as the reference's ``np.bincount``.
        mode: 0 forces only, 1 blocks into ``blocks``, 2 blocks into ``data``.
    """
    t_count = tri.shape[0]
    q = np.empty((4, 3, 3))         # Q_uu, Q_uv, Q_vu, Q_vv of one triangle
    reduced = np.empty((2, 3, 3, 3))   # R[p, j, a, b]
    face = np.zeros((3, 3))         # the air's block (the same for all nine corner pairs)
    normal = np.empty(3)
    wu = np.empty(3)
    wv = np.empty(3)
    wu_dot = np.empty(3)
    wv_dot = np.empty(3)
    du = np.empty(3)
    dv = np.empty(3)
    fu = np.empty(3)
    fv = np.empty(3)
    ku = np.empty(3)
    kvv = np.empty(3)
    for e in range(t_count):
        i0, i1, i2 = tri[e, 0], tri[e, 1], tri[e, 2]
        cu0, cu1, cu2 = cu[e, 0], cu[e, 1], cu[e, 2]
        cv0, cv1, cv2 = cv[e, 0], cv[e, 1], cv[e, 2]
        a_e = area[e]
        sa = np.sqrt(a_e)
        for d in range(3):
            wu[d] = cu0 * x[i0, d] + cu1 * x[i1, d] + cu2 * x[i2, d]
            wv[d] = cv0 * x[i0, d] + cv1 * x[i1, d] + cv2 * x[i2, d]
            wu_dot[d] = cu0 * v[i0, d] + cu1 * v[i1, d] + cu2 * v[i2, d]
            wv_dot[d] = cv0 * v[i0, d] + cv1 * v[i1, d] + cv2 * v[i2, d]
        len_u = np.sqrt(wu[0] * wu[0] + wu[1] * wu[1] + wu[2] * wu[2])
        len_v = np.sqrt(wv[0] * wv[0] + wv[1] * wv[1] + wv[2] * wv[2])
        for d in range(3):
            du[d] = wu[d] / len_u
            dv[d] = wv[d] / len_v
        # Stretch C = √A(|w| − 1), ∇_k C = √A coef_k ŵ; shear C = √A w_u·w_v.
        c_u = sa * (len_u - 1.0)
        c_v = sa * (len_v - 1.0)
        along_u = du[0] * wu_dot[0] + du[1] * wu_dot[1] + du[2] * wu_dot[2]
        along_v = dv[0] * wv_dot[0] + dv[1] * wv_dot[1] + dv[2] * wv_dot[2]
        cdot_u = sa * along_u
        cdot_v = sa * along_v
        c_s = sa * (wu[0] * wv[0] + wu[1] * wv[1] + wu[2] * wv[2])
        cdot_s = sa * ((wv[0] * wu_dot[0] + wv[1] * wu_dot[1] + wv[2] * wu_dot[2])
                       + (wu[0] * wv_dot[0] + wu[1] * wv_dot[1] + wu[2] * wv_dot[2]))
        conditions[0, e] = c_u
        conditions[1, e] = c_v
        conditions[2, e] = c_s
        conditions[3, e] = len_u
        conditions[4, e] = len_v
        # f_k = −k (C + βĊ) ∇_k C = coef_u_k F_u + coef_v_k F_v.
        shear_force = -ksh * (c_s + bsh * cdot_s) * sa
        s_u = -ks * sa * (c_u + bs * cdot_u)
        s_v = -ks * sa * (c_v + bs * cdot_v)
        # Kept stretch stiffness S = ŵŵᵀ + max(1 − 1/|w|, 0)(I − ŵŵᵀ); a NaN
        # stays NaN (as np.maximum), it is not clamped to 0.
        tens_u = 1.0 - 1.0 / len_u
        if tens_u < 0.0:
            tens_u = 0.0
        tens_v = 1.0 - 1.0 / len_v
        if tens_v < 0.0:
            tens_v = 0.0
        shear_kv = -ksh * cdot_s * sa
        k_area = -ks * a_e
        for d in range(3):
            fu[d] = s_u * du[d] + shear_force * wv[d]
            fv[d] = s_v * dv[d] + shear_force * wu[d]
            ku[d] = k_area * ((1.0 - tens_u) * along_u * du[d] + tens_u * wu_dot[d]) \
                + shear_kv * wv[d]
            kvv[d] = k_area * ((1.0 - tens_v) * along_v * dv[d] + tens_v * wv_dot[d]) \
                + shear_kv * wu[d]
        for k in range(3):
            node = tri[e, k]
            for d in range(3):
                force[node, d] += cu[e, k] * fu[d] + cv[e, k] * fv[d]
                kv[node, d] += cu[e, k] * ku[d] + cv[e, k] * kvv[d]
        if air_coef != 0.0:
            # Face drag along the normal, a third to each corner (forces.air_forces).
            e1x = x[i1, 0] - x[i0, 0]
            e1y = x[i1, 1] - x[i0, 1]
            e1z = x[i1, 2] - x[i0, 2]
            e2x = x[i2, 0] - x[i0, 0]
            e2y = x[i2, 1] - x[i0, 1]
            e2z = x[i2, 2] - x[i0, 2]
            cx = e1y * e2z - e1z * e2y
            cy = e1z * e2x - e1x * e2z
            cz = e1x * e2y - e1y * e2x
            twice_area = np.sqrt((cx * cx + cz * cz) + cy * cy)     # reference's sum order
            denom = max(twice_area, 2.2250738585072014e-308)      # 0 normal if collapsed
            nx, ny, nz = cx / denom, cy / denom, cz / denom
            rx = (v[i0, 0] + v[i1, 0] + v[i2, 0]) / 3.0 - wind[0]
            ry = (v[i0, 1] + v[i1, 1] + v[i2, 1]) / 3.0 - wind[1]
            rz = (v[i0, 2] + v[i1, 2] + v[i2, 2]) / 3.0 - wind[2]
            v_n = (nx * rx + nz * rz) + ny * ry
            k_face = air_coef * 0.5 * twice_area
            corner = -k_face * np.abs(v_n) * v_n / 3.0
            for k in range(3):
                node = tri[e, k]
                air_force[node, 0] += corner * nx
                air_force[node, 1] += corner * ny
                air_force[node, 2] += corner * nz
            if mode != 0:
                scale = c_d * 2.0 * k_face * np.abs(v_n) / 9.0
                normal[0], normal[1], normal[2] = nx, ny, nz
                for a in range(3):
                    for b in range(3):
                        face[a, b] = scale * normal[a] * normal[b]
        if mode == 0:
            continue
        # Blocks Σ_pq c_p[i] c_q[j] Q_pq (forces._membrane_blocks): stretch
        # k_s A [(cK + cD β) ŵŵᵀ + cK max(1 − 1/|w|, 0)(I − ŵŵᵀ)], shear
        # (cK + cD β_sh) k_sh A ∇C ∇Cᵀ / A, in the reference's operation order.
        along = ks * a_e * (c_k + c_d * bs)
        across_scale = ks * a_e * c_k
        shear_area = (c_k + c_d * bsh) * ksh * a_e
        across_u = across_scale * tens_u
        across_v = across_scale * tens_v
        for a in range(3):
            for b in range(3):
                eye = 1.0 if a == b else 0.0
                q[0, a, b] = ((along - across_u) * du[a] * du[b] + across_u * eye) \
                    + shear_area * wv[a] * wv[b]
                q[3, a, b] = ((along - across_v) * dv[a] * dv[b] + across_v * eye) \
                    + shear_area * wu[a] * wu[b]
                q[1, a, b] = shear_area * wv[a] * wu[b]
        for a in range(3):
            for b in range(3):
                q[2, a, b] = q[1, b, a]
        # R_p[j] = Σ_q c_q[j] Q_pq, then B[i, j] = Σ_p c_p[i] R_p[j] + the air's.
        for j in range(3):
            cuj, cvj = cu[e, j], cv[e, j]
            for a in range(3):
                for b in range(3):
                    reduced[0, j, a, b] = cuj * q[0, a, b] + cvj * q[1, a, b]
                    reduced[1, j, a, b] = cuj * q[2, a, b] + cvj * q[3, a, b]
        for i in range(3):
            cui, cvi = cu[e, i], cv[e, i]
            for j in range(3):
                start = 0 if mode == 1 else slots[e, i, j]
                for a in range(3):
                    for b in range(3):
                        value = (cui * reduced[0, j, a, b] + cvi * reduced[1, j, a, b]) \
                            + face[a, b]
                        if mode == 1:
                            blocks[e, 27 * i + 9 * a + 3 * j + b] = value
                        else:
                            data[start + 3 * a + b] += value


@_jit
def _hinge_geometry(x, a0, a1, b0, b1, g):
    """θ (rad) of hinge ``(a0, a1, b0, b1)`` (edge, then the opposite vertices) at
    positions x ``(n, 3)`` m, and ``∂θ/∂x`` into ``g`` ``(12,)`` 1/m: the
    operations of forces.hinge_angles, in its order (Bridson et al. 2003)."""
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
def _hinges(hv, weight, x, v, kb, bb, c_k, c_d, force, kv, theta, grad,
            blocks, slots, data, mode):
    """Bend of every hinge, ``C_b = √c_e θ`` (seed paper §5; design §2).

    Args:
        hv ``(h, 4)`` int64 ``(e0, e1, o0, o1)``; weight ``(h,)`` c_e; x, v
        ``(n, 3)``; kb N·m; bb s; c_k, c_d block weights.
        force, kv: ``(n, 3)`` zeroed outputs (N, N/s), summed in (hinge,
            vertex) order like the reference's ``np.bincount``.
        theta ``(h,)`` rad and grad ``(h, 4, 3)`` 1/m: outputs, θ and ∂θ/∂x
            (Bridson et al. 2003, as forces.hinge_angles).
        blocks: ``(h, 144)`` output ``[e, i, a, j, b]`` (mode 1); slots
            ``(h, 4, 4)`` and data: as :func:`_membrane`'s (mode 2).
    """
    h_count = hv.shape[0]
    g = np.empty(12)
    for h in range(h_count):
        th = _hinge_geometry(x, hv[h, 0], hv[h, 1], hv[h, 2], hv[h, 3], g)
        theta[h] = th
        theta_dot = 0.0
        for k in range(4):
            node = hv[h, k]
            for d in range(3):
                grad[h, k, d] = g[3 * k + d]
                theta_dot += g[3 * k + d] * v[node, d]
        s_force = -kb * weight[h] * (th + bb * theta_dot)
        s_kv = -kb * weight[h] * theta_dot
        for k in range(4):
            node = hv[h, k]
            for d in range(3):
                force[node, d] += s_force * g[3 * k + d]
                kv[node, d] += s_kv * g[3 * k + d]
        if mode == 0:
            continue
        # Gauss–Newton block (cK + cD β_b) k_b c_e ∇θ ∇θᵀ, rows (i, a), columns (j, b).
        scale = (c_k + c_d * bb) * kb * weight[h]
        if mode == 1:
            for r in range(12):
                scaled = scale * g[r]
                for c in range(12):
                    blocks[h, 12 * r + c] = scaled * g[c]
            continue
        for i in range(4):
            for j in range(4):
                start = slots[h, i, j]       # block (i, j): 9 consecutive entries
                for a in range(3):
                    scaled = scale * g[3 * i + a]
                    for b in range(3):
                        data[start + 3 * a + b] += scaled * g[3 * j + b]


@_jit
def _angles(hv, x, theta, grad, with_gradient):
    """θ ``(h,)`` rad and, if ``with_gradient``, ∂θ/∂x ``(h, 4, 3)`` 1/m of the
    hinges ``hv`` ``(h, 4)`` at positions x ``(n, 3)`` m (forces.hinge_angles)."""
    g = np.empty(12)
    for h in range(hv.shape[0]):
        theta[h] = _hinge_geometry(x, hv[h, 0], hv[h, 1], hv[h, 2], hv[h, 3], g)
        if with_gradient:
            for k in range(4):
                for d in range(3):
                    grad[h, k, d] = g[3 * k + d]


@_jit
def _stretches(tri, cu, cv, x, out):
    """``out`` ``(3, t)``: ``|w_u|``, ``|w_v|`` and ``w_u · w_v`` of every triangle
    at positions x ``(n, 3)`` m (BW §4.2; forces.elastic_energies' measures)."""
    for e in range(tri.shape[0]):
        uu = vv = uv = 0.0
        for d in range(3):
            wu = cu[e, 0] * x[tri[e, 0], d] + cu[e, 1] * x[tri[e, 1], d] \
                + cu[e, 2] * x[tri[e, 2], d]
            wv = cv[e, 0] * x[tri[e, 0], d] + cv[e, 1] * x[tri[e, 1], d] \
                + cv[e, 2] * x[tri[e, 2], d]
            uu += wu * wu
            vv += wv * wv
            uv += wu * wv
        out[0, e] = np.sqrt(uu)
        out[1, e] = np.sqrt(vv)
        out[2, e] = uv


@_jit
def _scatter_slots(slots, offset, values, data):
    """``data[slots[offset + k]] += values[k]`` in k order (np.bincount's order)."""
    for k in range(values.shape[0]):
        data[slots[offset + k]] += values[k]


@_jit
def _add_diagonal(diagonal_block, diagonal, data):
    """Add ``diagonal[i] I₃`` to vertex i's diagonal block of flat data ``(9 blocks,)``."""
    for i in range(diagonal.shape[0]):
        base = 9 * diagonal_block[i]
        data[base] += diagonal[i]
        data[base + 4] += diagonal[i]
        data[base + 8] += diagonal[i]


def _as_index(a: np.ndarray) -> np.ndarray:
    """``np.ascontiguousarray(a, dtype=np.int64)``; ``a`` itself without a numpy
    call when it is that already (the kernels' wrappers make thousands of
    these calls per second of an adaptive run)."""
    if type(a) is np.ndarray and a.dtype == np.int64 and a.ndim and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=np.int64)


def _as_float(a: np.ndarray) -> np.ndarray:
    """``np.ascontiguousarray(a, dtype=np.float64)``, as :func:`_as_index`."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.ndim and a.flags.c_contiguous:
        return a
    return np.ascontiguousarray(a, dtype=np.float64)


def evaluate(elements, material, x: np.ndarray, v: np.ndarray,
             stiffness_weight: float = 0.0, damping_weight: float = 0.0,
             with_blocks: bool = True, air=None, pattern=None):
    """:func:`cloth_lod_ros.sim.forces.evaluate` with the compiled kernels when
    :func:`enabled` (else the reference itself): the same arguments and result.

    ``pattern``: the topology's :class:`~cloth_lod_ros.sim.linear.SparsePattern`.
    Given it (and blocks wanted), the kernels add the blocks straight into the
    pattern's BSR data instead of returning ``triangle_blocks``/``hinge_blocks``
    (None then): the result's ``assembled`` is that ``(blocks, 3, 3)`` data
    without the diagonal, for :func:`assemble`.
    """
    if not _enabled:
        return _forces.evaluate(elements, material, x, v, stiffness_weight, damping_weight,
                         with_blocks, air)
    n = elements.vertex_count
    x = np.ascontiguousarray(x, dtype=np.float64)
    v = np.ascontiguousarray(v, dtype=np.float64)
    tri, hv = _as_index(elements.triangles), _as_index(elements.hinge_vertices)
    t_count, h_count = len(tri), len(hv)
    fused = with_blocks and pattern is not None
    mode = 0 if not with_blocks else (2 if fused else 1)
    air_coef = 0.0 if air is None else 0.5 * air.density * air.drag_coefficient
    wind = np.zeros(3) if air is None else np.asarray(air.wind, dtype=np.float64)
    cK, cD = float(stiffness_weight), float(damping_weight)
    scratch = np.empty(0)
    data = np.zeros(9 * pattern.block_count) if fused else scratch
    tri_slots, hinge_slots = pattern.block_slots if fused else (
        np.empty((0, 3, 3), dtype=np.int64), np.empty((0, 4, 4), dtype=np.int64))
    tri_blocks = np.empty((t_count, 81)) if mode == 1 else np.empty((0, 81))
    hinge_blocks = np.empty((h_count, 144)) if mode == 1 else np.empty((0, 144))

    force, kv, air_force = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    conditions = np.empty((5, t_count))
    _membrane(tri, elements.coef_u, elements.coef_v, elements.area, x, v,
              float(material.stretch_stiffness), float(material.shear_stiffness),
              float(material.stretch_damping), float(material.shear_damping),
              cK, cD, air_coef, wind, force, kv, air_force, conditions,
              tri_blocks, tri_slots, data, mode)
    hinge_force, hinge_kv = np.zeros((n, 3)), np.zeros((n, 3))
    theta, grad = np.empty(h_count), np.empty((h_count, 4, 3))
    kb, weight = float(material.bend_stiffness), elements.hinge_weight
    _hinges(hv, weight, x, v, kb, float(material.bend_damping), cK, cD,
            hinge_force, hinge_kv, theta, grad, hinge_blocks, hinge_slots, data, mode)
    # The reference adds the hinge sums to the membrane sums, then the air's.
    force += hinge_force
    kv += hinge_kv
    if air is not None:
        force += air_force

    result = _forces.summarise(
        material, conditions, weight, theta, grad, force, kv,
        tri_blocks.reshape(t_count, 3, 3, 3, 3) if mode == 1 else None,
        hinge_blocks.reshape(h_count, 4, 3, 4, 3) if mode == 1 else None)
    result.assembled = data.reshape(-1, 3, 3) if fused else None
    return result


def assemble(pattern, evaluation, diagonal: np.ndarray):
    """The system matrix of ``evaluation`` on ``pattern`` plus ``diagonal[i] I₃``
    per vertex (``diagonal`` ``(n,)``): :meth:`SparsePattern.assemble` of its
    blocks, or its already assembled data (:func:`evaluate` with a pattern)."""
    data = getattr(evaluation, "assembled", None)
    if data is None:
        return pattern.assemble([evaluation.triangle_blocks, evaluation.hinge_blocks],
                                diagonal)
    # A copy: the evaluation may be reused (a contact re-solve of the same
    # state) and finish() adds the diagonal in place.
    return pattern.finish(data.copy(), diagonal)


def hinge_angles(x: np.ndarray, hinge_vertices: np.ndarray, with_gradient: bool = False):
    """:func:`cloth_lod_ros.sim.forces.hinge_angles` (θ ``(h,)`` rad, optionally
    ∂θ/∂x ``(h, 4, 3)`` 1/m) by the compiled kernel when :func:`enabled`:
    bitwise the same numbers."""
    if not _enabled:
        return _forces.hinge_angles(x, hinge_vertices, with_gradient)
    hv = _as_index(hinge_vertices).reshape(-1, 4)
    theta = np.empty(len(hv))
    grad = np.empty((len(hv), 4, 3) if with_gradient else (0, 4, 3))
    _angles(hv, np.ascontiguousarray(x, dtype=np.float64), theta, grad, with_gradient)
    return (theta, grad) if with_gradient else theta


def _measures(elements, x: np.ndarray) -> np.ndarray:
    out = np.empty((3, len(elements.triangles)))
    _stretches(_as_index(elements.triangles), elements.coef_u, elements.coef_v,
               np.ascontiguousarray(x, dtype=np.float64), out)
    return out


def stretch_lengths(elements, x: np.ndarray) -> np.ndarray:
    """:func:`cloth_lod_ros.sim.forces.stretch_lengths` (``(t, 2)``), compiled
    when :func:`enabled` (equal to round-off)."""
    if not _enabled:
        return _forces.stretch_lengths(elements, x)
    return _measures(elements, x)[:2].T.copy()


def elastic_energies(elements, material, x: np.ndarray) -> dict:
    """:func:`cloth_lod_ros.sim.forces.elastic_energies` (J, and the max
    strain), compiled when :func:`enabled` (equal to round-off)."""
    if not _enabled:
        return _forces.elastic_energies(elements, material, x)
    len_u, len_v, shear = _measures(elements, x)
    area = elements.area
    theta = hinge_angles(x, elements.hinge_vertices)
    strain = np.concatenate([np.abs(len_u - 1.0), np.abs(len_v - 1.0)])
    return dict(
        stretch=float(0.5 * material.stretch_stiffness
                      * np.sum(area * ((len_u - 1.0)**2 + (len_v - 1.0)**2))),
        shear=float(0.5 * material.shear_stiffness * np.sum(area * shear**2)),
        bend=float(0.5 * material.bend_stiffness * np.sum(elements.hinge_weight * theta**2)),
        max_strain=float(strain.max()) if len(strain) else 0.0)
