"""Compiled (numba) measures of a state: the stretch of every triangle (the
step's strain test) and the elastic energies (the statistics), as
:mod:`cloth_lod_ros.sim.physics.energies` computes them (equal to round-off).
"""

from __future__ import annotations

import numpy as np

from ..runtime.compiled import _as_index, _jit, enabled
from . import energies as _energies
from .bending import bend_energy

__all__ = ["stretch_lengths", "elastic_energies"]


@_jit
def _stretches(tri, cu, cv, x, out):
    """``out`` ``(3, t)``: ``|w_u|``, ``|w_v|`` and ``w_u · w_v`` of every triangle
    at positions x ``(n, 3)`` m (BW §4.2; energies.elastic_energies' measures)."""
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


def _measures(elements, x: np.ndarray) -> np.ndarray:
    out = np.empty((3, len(elements.triangles)))
    _stretches(_as_index(elements.triangles), elements.coef_u, elements.coef_v,
               np.ascontiguousarray(x, dtype=np.float64), out)
    return out


def stretch_lengths(elements, x: np.ndarray) -> np.ndarray:
    """:func:`cloth_lod_ros.sim.physics.energies.stretch_lengths` (``(t, 2)``), compiled
    when :func:`enabled` (equal to round-off)."""
    if not enabled():
        return _energies.stretch_lengths(elements, x)
    return _measures(elements, x)[:2].T.copy()


def elastic_energies(elements, material, x: np.ndarray) -> dict:
    """:func:`cloth_lod_ros.sim.physics.energies.elastic_energies` (J, and the max
    strain), compiled when :func:`enabled` (equal to round-off)."""
    if not enabled():
        return _energies.elastic_energies(elements, material, x)
    len_u, len_v, shear = _measures(elements, x)
    area = elements.area
    strain = np.concatenate([np.abs(len_u - 1.0), np.abs(len_v - 1.0)])
    return dict(
        stretch=float(0.5 * material.stretch_stiffness
                      * np.sum(area * ((len_u - 1.0)**2 + (len_v - 1.0)**2))),
        shear=float(0.5 * material.shear_stiffness * np.sum(area * shear**2)),
        bend=bend_energy(elements.bend, material.bend_stiffness, x),
        max_strain=float(strain.max()) if len(strain) else 0.0)
