"""Loading the compiled (numba) kernels once per process, before the first timed step."""

from __future__ import annotations

import logging
import time as _time

from . import (check_kernels, compact_kernels, hierarchy_kernels, kernels, lod_kernels,
               multigrid_kernels, pattern_kernels, projection_kernels, round_kernels,
               self_kernels, topology_kernels)
from .config import load_scene
from .solvers import available_methods

__all__ = ["warm_up_compiled_code"]

log = logging.getLogger(__name__)

_WARMED_UP = False


def warm_up_compiled_code() -> float:
    """Load the compiled (numba) kernels a step uses, once per process; seconds spent.

    A step's first call of each kernel loads it from the on-disk cache (about
    0.5 s in all) or, the first time on a machine, compiles it (several
    seconds).  Stepping a tiny cloth with LOD and self-collision on here, when
    the first :class:`ClothSim` is built, moves that cost out of the first step
    of the real one, and out of the LOD and self-collision timers: a node's
    first frame, a benchmark's first timed step.  Nothing without numba.
    """
    global _WARMED_UP
    if _WARMED_UP or not kernels.enabled():
        return 0.0
    _WARMED_UP = True                       # before the tiny ClothSim, which calls this
    start = _time.perf_counter()
    try:
        from .cloth import ClothSim       # which calls this when built
        tiny = ClothSim(load_scene("hang_two_corners",
                                   ["cloth.level=2", "self_collision.enabled=true"]))
        tiny.step()
        topology_kernels.warm_up()  # a topology change's kernels, whatever the tiny step did
        pattern_kernels.warm_up()   # and its sparsity pattern's
        hierarchy_kernels.warm_up()  # split/merge and a whole LOD decision
        self_kernels.warm_up()      # the broad phase's kernels a folded cloth needs
        projection_kernels.warm_up()  # sliding contacts' projection, if the tiny step had none
        lod_kernels.warm_up()       # the LOD criterion's, whether or not the tiny step merged
        check_kernels.warm_up()     # and a plain check's in one call
        multigrid_kernels.warm_up()  # the V-cycle a large cloth's solves use
        round_kernels.warm_up()     # a check's later rounds, on the hierarchy's pools
        compact_kernels.warm_up()   # a topology change's compact mesh and held patches
        if "block_ldl" in available_methods():
            from . import trailing_ldl   # imports numba, like block_ldl
            trailing_ldl.warm_up()  # contact rounds on one factorisation
    except Exception as exc:    # never a reason to refuse the real scene: it only costs time
        log.warning("compiled kernels not warmed up (%s); the first step loads them", exc)
    return _time.perf_counter() - start


