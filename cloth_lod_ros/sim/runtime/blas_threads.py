"""One BLAS thread inside a simulation step (design §3, "Linear solvers").

The dense work of a step is small: the trailing rounds' Cholesky of
``3|C|`` unknowns (:mod:`cloth_lod_ros.sim.solve.trailing_ldl`, LAPACK through
numba), 3 × 3 blocks, a few matrix products.  numpy's and scipy's OpenBLAS start one thread per
core and split such calls between them, which buys nothing at these sizes
and costs twice over:

* the worker threads spin between calls: on the 2-core CI VM a driven
  ``grasp_lift`` took 21.3 s of CPU for 14.2 s of wall time, 13.8 s with one
  thread (the same wall time) - in the node that second core is the one its
  input threads, the recorder and the other nodes need;
* a blocked LAPACK call sums in an order that depends on the thread count,
  so the trajectory depended on the machine's cores at round-off (a bag
  recorded by the node replayed exactly on two cores and diverged from
  t = 1.28 s on one), which the bag replay's bit-for-bit check rules out.

:func:`one_blas_thread` limits every loaded BLAS to one thread for the
duration of a step (``threadpoolctl``, about 16 µs per step) and restores the
caller's setting afterwards, so code around the simulator keeps its own.
cvxopt's OpenBLAS (the optional ``cholmod`` backend) is loaded with one
thread already (:func:`~cloth_lod_ros.sim.solve.backends._cholmod_modules`).
"""

from __future__ import annotations

from threadpoolctl import ThreadpoolController

__all__ = ["one_blas_thread", "forget_libraries"]

_controller: ThreadpoolController | None = None


def one_blas_thread():
    """A context manager: one thread in every BLAS loaded (numpy's, scipy's)."""
    global _controller
    if _controller is None:
        # Lists the loaded libraries once (about 4 ms): they are loaded by
        # numpy and scipy's imports, before any step.
        _controller = ThreadpoolController()
    return _controller.limit(limits=1, user_api="blas")


def forget_libraries() -> None:
    """List the loaded BLAS libraries again at the next step (after loading
    one, e.g. an optional backend's)."""
    global _controller
    _controller = None
