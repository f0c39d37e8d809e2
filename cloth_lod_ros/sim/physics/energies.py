"""Energies (J) and stretches of a state without forces or Jacobians: the
statistics, the step's strain test, the membrane energy of a merge
(design §2).  Compiled: :mod:`.energies_kernels`.
"""

from __future__ import annotations

import numpy as np

from .elements import Elements
from .bending import bend_energy
from .vectors import _dot

__all__ = ["elastic_energies", "stretch_lengths", "membrane_energies"]


def membrane_energies(coef_u: np.ndarray, coef_v: np.ndarray, area: np.ndarray,
                      corners: np.ndarray, material) -> np.ndarray:
    """Stretch + shear energy of each triangle, J, ``(t,)`` (design §2).

    Args:
        coef_u, coef_v, area: from :func:`triangle_maps`.
        corners: ``(t, 3, 3)`` positions of each triangle's corners, m.
        material: with ``stretch_stiffness`` and ``shear_stiffness`` (N/m).
    """
    wu = np.einsum("tk,tkd->td", coef_u, corners)
    wv = np.einsum("tk,tkd->td", coef_v, corners)
    len_u, len_v = np.sqrt(_dot(wu, wu)), np.sqrt(_dot(wv, wv))
    return 0.5 * area * (material.stretch_stiffness * ((len_u - 1.0)**2 + (len_v - 1.0)**2)
                         + material.shear_stiffness * _dot(wu, wv)**2)


def elastic_energies(elements: Elements, material, x: np.ndarray) -> dict:
    """Stretch, shear and bend energies (J) and max strain at positions ``x`` (m).

    The cheap path for statistics: no gradients, no blocks.
    """
    xt = x[elements.triangles]
    wu = np.einsum("tk,tkd->td", elements.coef_u, xt)
    wv = np.einsum("tk,tkd->td", elements.coef_v, xt)
    len_u, len_v = np.sqrt(_dot(wu, wu)), np.sqrt(_dot(wv, wv))
    area = elements.area
    strain = np.concatenate([np.abs(len_u - 1.0), np.abs(len_v - 1.0)])
    return dict(
        stretch=float(0.5 * material.stretch_stiffness
                      * np.sum(area * ((len_u - 1.0)**2 + (len_v - 1.0)**2))),
        shear=float(0.5 * material.shear_stiffness * np.sum(area * _dot(wu, wv)**2)),
        bend=bend_energy(elements.bend, material.bend_stiffness, x),
        max_strain=float(strain.max()) if len(strain) else 0.0)


def stretch_lengths(elements: Elements, x: np.ndarray) -> np.ndarray:
    """``(t, 2)`` stretch ``|w_u|, |w_v|`` of every triangle at positions ``x`` (m);
    1 is the rest length, so ``|w| − 1`` is the strain."""
    xt = x[elements.triangles]
    wu = np.einsum("tk,tkd->td", elements.coef_u, xt)
    wv = np.einsum("tk,tkd->td", elements.coef_v, xt)
    return np.column_stack([np.sqrt(_dot(wu, wu)), np.sqrt(_dot(wv, wv))])
