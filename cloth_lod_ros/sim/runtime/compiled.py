"""The switch between the compiled (numba) kernels and the numpy reference.

Every ``*_kernels`` module compiles the numpy code of the module it pairs with
and runs it only when :func:`enabled`: numba imports and the environment
variable ``CLOTH_LOD_KERNELS`` is not ``numpy`` (``numba``/``auto``/unset:
compiled if available); :func:`use` switches at run time (tests,
benchmarks).  Without numba everything falls back to the numpy reference,
which stays the definition.

The kernels are compiled on first use and cached next to their module
(``cache=True``: ``__pycache__/<module>.*.nbi``/``.nbc``), so a later process
only loads them.  ``error_model="numpy"``: a degenerate element (a zero-length
edge or normal) gives inf/nan like the numpy code instead of raising.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["available", "enabled", "use"]


try:
    import numba
except ImportError:                 # pragma: no cover - exercised without numba
    numba = None


#: Whether numba imported (the compiled path can be used at all).
available = numba is not None
_enabled = available and os.environ.get("CLOTH_LOD_KERNELS", "auto").lower() != "numpy"


def enabled() -> bool:
    """Whether the ``*_kernels`` modules run their compiled kernels (else the
    numpy reference)."""
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
