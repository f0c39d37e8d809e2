"""Compiling or loading the numba kernels a scene needs, before its first step.

A kernel's first call in a process loads it from numba's on-disk cache (tens of ms)
or, the first time on a machine, compiles it (seconds).  :func:`warm_up_compiled_code`
runs when a :class:`~cloth_lod_ros.sim.ClothSim` is built and calls the kernels the
scene will use on tiny inputs, so that no timed step (a node's frame, a benchmark's
step) stops for either; ``test/sim/test_warm_up.py`` checks that a scene's run then
compiles nothing.

Only the groups the scene needs are prepared (:func:`plan`): no self-collision
kernels when it is off, no LOD kernels on a uniform mesh, no multigrid unless the
solver can choose it for the cloth's size, no trailing factorisation without contact.
A later simulator in the same process that needs more (another scene, a reset with
other settings) prepares the rest when it is built, with the same log lines; a kernel
compiled outside a warm-up (a signature no group foresaw) is logged as it happens.

Progress goes to this module's logger at INFO: one line when a group starts
compiling (never for a group loaded from the cache), a line every
:data:`HEARTBEAT` seconds while one compiles, and one when all are ready.  The node
and ``cloth-lod`` show them (``ros/startup.py`` prints the line before).

:attr:`KernelGroup.compile_s` is measured: CPU seconds (numba compiles on one core)
of the group's first compile in a process with an empty cache (``NUMBA_CACHE_DIR``
pointed at a new directory), the groups in :data:`GROUPS` order, on a 2-core x86_64
machine (AMD EPYC, numba 0.68.1, llvmlite 0.50); wall time is 2-4x that when the
machine is busy.  The default scene needs 62 s of the 104 s that every group takes.
Background compilation after the first frame was measured and not adopted (see
:func:`warm_up_compiled_code`).
"""

from __future__ import annotations

import logging
import threading
import time as _time
from dataclasses import dataclass
from typing import Callable

from .contact import self_broad_kernels
from .lod import check_kernels, merge_energy_kernels, policy_kernels, round_kernels
from .physics import elements_kernels
from .mesh import hierarchy
from .inputs import holding_kernels
from .runtime import compiled
from .solve import multigrid_kernels, pattern_kernels, projection_kernels
from .scene.config import SceneConfig, load_scene, self_collision_on
from .solve.backends import available_methods, make_solver

__all__ = ["KernelGroup", "GROUPS", "plan", "warm_up_compiled_code", "HEARTBEAT"]

log = logging.getLogger(__name__)

#: s between "still compiling" lines while one group compiles.
HEARTBEAT = 15.0


def _uniform_particles(scene: SceneConfig) -> int:
    """Particles of the cloth refined uniformly to ``cloth.level``: the most an
    adaptive mesh can have.  A 4-8 mesh (:mod:`cloth_lod_ros.sim.mesh.mesh48`, paper §3) at level 2k
    is the (bu·2^k + 1) x (bv·2^k + 1) grid of its blocks' corners; level 2k + 1
    adds each of the bu·bv·4^k cells' centres."""
    bu, bv = scene.cloth.base_blocks
    k, odd = divmod(scene.cloth.level, 2)
    grid = (bu * 2 ** k + 1) * (bv * 2 ** k + 1)
    return grid + (bu * bv * 4 ** k if odd else 0)


def _block_ldl(scene: SceneConfig) -> bool:
    return scene.solver.method in ("auto", "block_ldl") and "block_ldl" in available_methods()


def _multigrid(scene: SceneConfig) -> bool:
    """The solver is multigrid, or ``auto`` on a cloth that can outgrow its
    direct limit (the uniform one, the lower: a fully refined mesh is uniform)."""
    if scene.solver.method == "multigrid":
        return True
    if scene.solver.method != "auto":
        return False
    limit = make_solver("auto", scene.solver.tolerance, 1).limits[0]
    return _uniform_particles(scene) > limit


def _contact(scene: SceneConfig) -> bool:
    """Contact rounds on one block factorisation (:mod:`cloth_lod_ros.sim.solve.trailing_ldl`): a
    direct block solver and something to touch."""
    return _block_ldl(scene) and bool(scene.obstacles or self_collision_on(scene))


def _tiny_step(scene: SceneConfig, simulator: type) -> None:
    """Two steps of a level-2 cloth with the scene's solver and features (LOD,
    self-collision): what a step calls that no group's kernels cover."""
    tiny = simulator(load_scene("hang_two_corners", [
        "cloth.level=2", f"lod.enabled={str(scene.lod.enabled).lower()}",
        f"self_collision.enabled={str(self_collision_on(scene)).lower()}",
        f"solver.method={scene.solver.method}"]))
    tiny.step()
    tiny.step()


def _trailing(scene: SceneConfig, simulator: type) -> None:
    from .solve import trailing_ldl          # imports numba, like block_ldl
    trailing_ldl.warm_up()


@dataclass(frozen=True)
class KernelGroup:
    """Kernels prepared together, for scenes that need them."""
    name: str
    label: str                                  # for the log lines
    compile_s: float                            # s of CPU, measured (module docstring)
    needed: Callable[[SceneConfig], bool]
    run: Callable[[SceneConfig, type], None]    # calls the kernels on tiny inputs
                                                # (the scene, the ClothSim class)
    variant: Callable[[SceneConfig], tuple] = lambda scene: ()   # what ``run`` depends on

    def key(self, scene: SceneConfig) -> tuple:
        return (self.name, *self.variant(scene))


def _always(scene):
    return True


def _lod(scene):
    return scene.lod.enabled


#: In the order they are prepared: each module's own warm-up first (named lines
#: while compiling), the tiny step last (forces, assembly, the block LDLᵀ, and
#: whatever a whole step adds).
GROUPS = (
    KernelGroup("topology", "mesh topology kernels", 5.5, _always,
                lambda s, sim: elements_kernels.warm_up()),
    KernelGroup("pattern", "sparsity pattern kernels", 5.0, _always,
                lambda s, sim: pattern_kernels.warm_up()),
    KernelGroup("projection", "constraint projection kernels", 3.5, _always,
                lambda s, sim: projection_kernels.warm_up()),
    KernelGroup("hierarchy", "LOD hierarchy kernels (split, merge)", 16.0, _lod,
                lambda s, sim: hierarchy.warm_up()),
    KernelGroup("lod", "LOD criterion kernels", 12.0, _lod,
                lambda s, sim: (policy_kernels.warm_up(), merge_energy_kernels.warm_up())),
    KernelGroup("check", "LOD check kernels", 4.0, _lod, lambda s, sim: check_kernels.warm_up()),
    KernelGroup("round", "LOD round kernels", 5.0, _lod, lambda s, sim: round_kernels.warm_up()),
    KernelGroup("compact", "compact mesh and held patch kernels", 1.5,
                lambda s: s.lod.enabled or bool(s.grasps), lambda s, sim: holding_kernels.warm_up()),
    KernelGroup("self", "self-collision kernels", 26.0, self_collision_on,
                lambda s, sim: self_broad_kernels.warm_up()),
    KernelGroup("multigrid", "multigrid kernels", 5.5, _multigrid,
                lambda s, sim: multigrid_kernels.warm_up()),
    KernelGroup("trailing", "contact round (trailing LDL) kernels", 10.5, _contact, _trailing),
    KernelGroup("step", "step kernels (forces, assembly, linear solver)", 9.5, _always,
                _tiny_step, variant=lambda s: (s.lod.enabled, self_collision_on(s),
                                               s.solver.method)),
)

_lock = threading.RLock()
_done: set = set()              # keys of the groups prepared in this process
_active = threading.local()     # set while this thread prepares (the tiny step's ClothSim)


def plan(scene: SceneConfig) -> list:
    """The groups ``scene`` needs that this process has not prepared yet, in order."""
    return [g for g in GROUPS if g.needed(scene) and g.key(scene) not in _done]


def _every_variant() -> list:
    """Scenes that together need every group in every variant: the default
    scene with LOD and self-collision on and off, and with the multigrid solver."""
    return [load_scene("hang_two_corners", [f"lod.enabled={lod}",
                                            f"self_collision.enabled={self_collision}"])
            for lod in ("true", "false") for self_collision in ("false", "true")] + [
        load_scene("hang_two_corners", ["solver.method=multigrid"])]


class _Compiles:
    """numba's ``numba:compile`` events (a cache miss compiling: not a cache
    load) turned into log lines: which group compiles, a heartbeat, and any
    kernel compiled outside a warm-up (``numba.core.event``)."""

    def __init__(self):
        self.group = None               # (index, count, KernelGroup) while warming
        self.announced = set()
        self.depth = 0                  # nested events: a kernel's callees compile inside it
        self.kernel = ""
        self.kernels = 0                # top-level compiles during this warm-up
        self.started = 0.0
        self.outside = 0.0

    def on_start(self, name: str) -> None:
        if self.depth == 0:
            self.kernel = name
            if self.group is None:
                self.outside = _time.perf_counter()
                log.info("compiling %s (not prepared before the first step; the step "
                         "waits for it)...", name)
            elif self.group[0] not in self.announced:
                index, count, group = self.group
                self.announced.add(index)
                log.info("compiling %s (%d/%d), about %.0f s...", group.label, index, count,
                         group.compile_s)
        self.depth += 1

    def on_end(self) -> None:
        self.depth -= 1
        if self.depth == 0:
            if self.group is None:
                log.info("compiled %s in %.1f s", self.kernel,
                         _time.perf_counter() - self.outside)
            else:
                self.kernels += 1
            self.kernel = ""


_compiles = _Compiles()
_listening = False


def _listen() -> None:
    """Register :data:`_compiles` with numba once per process."""
    global _listening
    if _listening:
        return
    from numba.core import event

    class Listener(event.Listener):
        def on_start(self, ev):
            function = ev.data["dispatcher"].py_func
            _compiles.on_start(f"{function.__module__.rsplit('.', 1)[-1]}.{function.__name__}")

        def on_end(self, ev):
            _compiles.on_end()

    event.register("numba:compile", Listener())
    _listening = True


def _heartbeat(stop: threading.Event) -> None:
    while not stop.wait(HEARTBEAT):
        group, kernel = _compiles.group, _compiles.kernel
        if group is not None and kernel and group[0] in _compiles.announced:
            log.info("still compiling %s: %s (%.0f s so far)", group[2].label, kernel,
                     _time.perf_counter() - _compiles.started)


def warm_up_compiled_code(simulator: type, scene: SceneConfig | None = None) -> float:
    """Prepare the kernels ``scene`` needs (None: every group, in every variant)
    that this process has not prepared yet; seconds spent.  Nothing without numba.

    The groups a scene does not need are not compiled in a background thread
    after its first frame: measured on the 2-core machine (busy, load ~10), the
    default scene stepped as the node does (switch interval 0.2 ms) advanced
    10.9 s of simulated time in 20 s with the self-collision, multigrid and
    trailing groups compiling beside it, against 23.7 s without (median step
    28 against 13 ms, longest 316 against 71 ms): the compile takes a core and
    the GIL through numba's typing.  A later simulator that needs them prepares
    them when it is built.  A group that fails is logged and skipped: its
    kernels then compile at first use, which only costs time.

    Args:
        simulator: :class:`~cloth_lod_ros.sim.cloth.ClothSim`, the class of the
            tiny cloth the ``step`` group steps (the facade calls this when
            built and hands itself in: it imports this module, not the other
            way round).
        scene: the scene to prepare for.
    """
    if not compiled.enabled() or getattr(_active, "on", False):
        return 0.0
    with _lock:
        work, keys = [], set()
        for s in ([scene] if scene is not None else _every_variant()):
            for group in plan(s):
                if group.key(s) not in keys:
                    keys.add(group.key(s))
                    work.append((GROUPS.index(group), group, s))
        if not work:
            return 0.0
        work.sort(key=lambda item: item[0])
        _listen()
        _active.on = True
        _compiles.started = start = _time.perf_counter()
        _compiles.kernels = 0
        _compiles.announced = set()
        stop = threading.Event()
        threading.Thread(target=_heartbeat, args=(stop,), name="warm-up heartbeat",
                         daemon=True).start()
        try:
            for index, (_, group, s) in enumerate(work, 1):
                _compiles.group = (index, len(work), group)
                try:
                    group.run(s, simulator)
                except Exception as exc:    # never a reason to refuse the scene
                    log.warning("%s not prepared (%s); they compile at first use",
                                group.label, exc)
                _done.add(group.key(s))
        finally:
            _compiles.group = None
            _active.on = False
            stop.set()
        seconds = _time.perf_counter() - start
        if _compiles.kernels:
            labels = dict.fromkeys(g.label for i, (_, g, _) in enumerate(work, 1)
                                   if i in _compiles.announced)
            log.info("compiled kernels ready in %.1f s (%d kernels compiled: %s)", seconds,
                     _compiles.kernels, ", ".join(labels))
        else:
            log.info("compiled kernels loaded from the cache in %.1f s", seconds)
        return seconds
