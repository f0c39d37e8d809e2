"""What a direct backend's factorisation is of, so that a solve of the same
system with another right-hand side only back-substitutes; the count of
numeric factorisations; the compiled block LDLᵀ module when numba is there.
"""

from __future__ import annotations

import numpy as np

__all__ = ["factorisation_count"]


_BLOCK_LDL = None


def _block_ldl_module():
    """:mod:`cloth_lod_ros.sim.solve.block_ldl` (imports numba, ~0.5 s), or None without numba."""
    global _BLOCK_LDL
    if _BLOCK_LDL is None:
        try:
            from . import block_ldl
            _BLOCK_LDL = block_ldl
        except ImportError:
            _BLOCK_LDL = False
    return _BLOCK_LDL or None


def factorisation_count() -> int:
    """Numeric factorisations the direct backends have made in this process
    (a solve that reused one only back-substituted: :class:`_FactoredSystem`)."""
    return _FactoredSystem.factorisations


class _FactoredSystem:
    """What a direct backend's current factorisation is of: the matrix (the
    same object with the same numbers: the assembly reuses its storage) and
    the constraints' particles and filters.  A solve of the same system with
    another right-hand side or other prescribed values (the reactions passed
    to another layer, a friction round that changed no filter) then only
    back-substitutes.  ``factorisations`` counts the numeric factorisations."""

    factorisations = 0

    def __init__(self):
        self._key = None

    def holds(self, matrix, constraints) -> bool:
        key = self._key
        return (key is not None and key[0] is matrix
                and np.array_equal(key[1], matrix.data)
                and np.array_equal(key[2], constraints.indices)
                and np.array_equal(key[3], constraints.projectors))

    def remember(self, matrix, constraints) -> None:
        self._key = (matrix, matrix.data.copy(), constraints.indices.copy(),
                     constraints.projectors.copy())
        _FactoredSystem.factorisations += 1

    def forget(self) -> None:
        """Before a factorisation (one that fails leaves nothing valid)."""
        self._key = None
