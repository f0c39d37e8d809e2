"""Per-particle velocity constraints of a filtered solve (BW §5.3) and the
outcome of a linear solve.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Constraints", "SolveResult"]


@dataclass
class Constraints:
    """Per-particle velocity constraints for the filtered solve (BW §5.3).

    Attributes:
        indices: ``(k,)`` constrained particle indices.
        projectors: ``(k, 3, 3)`` filters ``S_i`` (0 = fully held, ``I − nnᵀ`` =
            held along n only).
        prescribed: ``(k, 3)`` prescribed velocity change ``z_i`` (m/s); only
            its ``(I − S_i)`` part is used.
    """

    indices: np.ndarray
    projectors: np.ndarray
    prescribed: np.ndarray

    @classmethod
    def none(cls) -> "Constraints":
        return cls(np.zeros(0, dtype=np.int64), np.zeros((0, 3, 3)), np.zeros((0, 3)))

    def filter(self, r: np.ndarray) -> np.ndarray:
        """Apply S to an ``(n, 3)`` vector (returns a new array)."""
        out = r.copy()
        if len(self.indices):
            out[self.indices] = np.einsum("kab,kb->ka", self.projectors, r[self.indices])
        return out

    def start(self, guess: np.ndarray) -> np.ndarray:
        """``S y + (I − S) z``: the corrected initial value."""
        out = self.filter(guess)
        if len(self.indices):
            held = self.prescribed - np.einsum("kab,kb->ka", self.projectors,
                                               self.prescribed)
            out[self.indices] += held
        return out


@dataclass
class SolveResult:
    """Outcome of one linear solve.

    Attributes:
        dv: ``(n, 3)`` velocity change, m/s.
        iterations: CG iterations (0 for the direct solver).
        residual: ``|S(b − A Δv)| / |S b|`` (2-norm; 0 if ``S b`` = 0).
        converged: whether ``residual`` met the tolerance.
    """

    dv: np.ndarray
    iterations: int
    residual: float
    converged: bool
