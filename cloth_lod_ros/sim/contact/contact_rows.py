"""The constraint geometry of contact rows with one or two obstacle normals (design §3).

A particle near two obstacles at once (``ContactSet.second``: a box pushing
it into the table) is held out of both: its velocity at the end of the stage
must satisfy ``nᵢ·v = tᵢ`` for both normals, which fixes its component in
the plane ``span(n₁, n₂)`` and leaves it free only along their common tangent
``n₁ × n₂``.  With ``N = [n₁ n₂]`` ``(3, 2)`` and ``G = NᵀN``:

* the velocity change that lands it, ``Δv = N G⁻¹ (t − Nᵀv)``;
* the projector onto the constrained plane ``P = N G⁻¹ Nᵀ`` (the filter of a
  sliding row is ``I − P``, BW §5.3's ``I − n nᵀ`` for one normal);
* the contact impulse ``R`` splits into normal loads ``λ = G⁻¹ NᵀR``
  (``P R = N λ``), one per obstacle, which say which obstacle pulls (is
  released) and bound Coulomb friction, ``|R − P R| ≤ Σ μᵢ λᵢ``.

A second normal is attached only when it is not nearly parallel or
opposite to the first (``contacts.SECOND_NORMAL_COS``), so ``G`` is well
conditioned (``det G = 1 − (n₁·n₂)² ≥ 0.067``).  Rows without a second
obstacle use the one-normal formulas of the integrator unchanged; this
module handles the doubled rows.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TwoNormals"]


class TwoNormals:
    """The doubled rows of a contact set.

    Args:
        n1, n2: ``(k, 3)`` unit normals of the first and second obstacle.
    """

    def __init__(self, n1: np.ndarray, n2: np.ndarray):
        self.n = np.stack([n1, n2], axis=1)                 # (k, 2, 3): rows of Nᵀ
        c = np.einsum("kd,kd->k", n1, n2)
        det = 1.0 - c * c
        # G⁻¹ = [[1, −c], [−c, 1]] / (1 − c²)
        self.g_inv = np.empty((len(c), 2, 2))
        self.g_inv[:, 0, 0] = self.g_inv[:, 1, 1] = 1.0 / det
        self.g_inv[:, 0, 1] = self.g_inv[:, 1, 0] = -c / det

    def normal_loads(self, vectors: np.ndarray) -> np.ndarray:
        """``(k, 2)``: ``λ = G⁻¹ Nᵀ r`` for ``r`` ``(k, 3)``, the components of
        ``P r`` along each normal (``P r = λ₁ n₁ + λ₂ n₂``)."""
        return np.einsum("kij,kj->ki", self.g_inv, np.einsum("kjd,kd->kj", self.n, vectors))

    def in_plane(self, vectors: np.ndarray) -> np.ndarray:
        """``(k, 3)``: ``P r``, the part of ``r`` ``(k, 3)`` in ``span(n₁, n₂)``."""
        return np.einsum("kj,kjd->kd", self.normal_loads(vectors), self.n)

    def landing(self, current: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """``(k, 3)`` m/s: the change in ``span(n₁, n₂)`` that gives velocities
        ``current`` ``(k, 3)`` the normal components ``targets`` ``(k, 2)`` m/s."""
        miss = targets - np.einsum("kjd,kd->kj", self.n, current)
        return np.einsum("kj,kjd->kd", np.einsum("kij,kj->ki", self.g_inv, miss), self.n)

    def free_projectors(self) -> np.ndarray:
        """``(k, 3, 3)``: ``I − P``, the filter of a row sliding on both surfaces."""
        p = np.einsum("kia,kij,kjb->kab", self.n, self.g_inv, self.n)
        return np.eye(3)[None] - p
