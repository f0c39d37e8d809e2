"""The switch between the compiled (numba) kernels and the numpy reference.

Every ``*_kernels`` module compiles the numpy code of the module it pairs with
and runs it only when :func:`enabled`: numba imports and the environment
variable ``CLOTH_LOD_KERNELS`` is not ``numpy`` (``numba``/``auto``/unset:
compiled if available); :func:`use` switches at run time (tests,
benchmarks).  Without numba everything falls back to the numpy reference,
which stays the definition.

The kernels are compiled on first use and cached next to their module
(``cache=True``: ``__pycache__/<module>.*.nbi``/``.nbc``), so a later process
only loads them.  numba keys a cached kernel on its own file's SHA-256 only: a
kernel whose callee (another module's kernel, or a constant it freezes at
compile time) changed would load stale machine code, which is what an upgrade
in place or an edit leaves behind.  :func:`key_caches_on_package` makes the
key every source of the simulator instead (``test/sim/runtime``).  ``error_model="numpy"``: a degenerate element (a zero-length
edge or normal) gives inf/nan like the numpy code instead of raising.
"""

from __future__ import annotations

import hashlib
import os
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["available", "enabled", "use", "package_stamp", "key_caches_on_package"]


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


@lru_cache(maxsize=None)
def package_stamp(root: Path) -> bytes:
    """SHA-256 of every ``.py`` under ``root`` (sorted relative paths and
    contents): the key of every cached kernel under ``root``.
    ``ros/startup.py`` computes the same to tell a warm cache from a stale one."""
    digest = hashlib.sha256()
    for path in sorted(p for p in Path(root).rglob("*.py") if "__pycache__" not in p.parts):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.digest()


def key_caches_on_package(root: Path) -> bool:
    """Key numba's cache of every kernel defined under ``root`` on
    :func:`package_stamp` (all of ``root``'s sources) instead of its own file's:
    numba's cache locators, each subclassed to claim only files under ``root``,
    ahead of numba's own.  Must run before the kernels are decorated (numba picks
    a kernel's locator then).  False if this numba has no locator list to extend
    (the kernels then keep numba's per-file key)."""
    from numba.core import caching
    root = Path(root).resolve()
    try:
        impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl   # renamed in 0.6x
        registry = impl._locator_classes
        bases = (caching.UserProvidedCacheLocator, caching.InTreeCacheLocator,
                 caching.UserWideCacheLocator)
    except AttributeError:          # pragma: no cover - another numba's internals
        return False
    if any(getattr(cls, "package_root", None) == root for cls in registry):
        return True

    class _PackageKey:
        package_root = root

        @classmethod
        def from_function(cls, py_func, py_file):
            try:
                if not Path(py_file).resolve().is_relative_to(root):
                    return None
            except OSError:
                return None
            return super().from_function(py_func, py_file)

        def get_source_stamp(self):
            return package_stamp(root)

    registry[:0] = [type(f"Package{base.__name__}", (_PackageKey, base), {}) for base in bases]
    return True


if available:
    key_caches_on_package(Path(__file__).resolve().parent.parent)     # the simulator
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
