"""The warm-up loads every kernel signature a simulation calls.

:func:`~cloth_lod_ros.sim.warm_up.warm_up_compiled_code` runs when the first
ClothSim is built, so that no timed step (a node's frame, a benchmark's step)
stops to compile or load a kernel.  A signature first met later (another
dtype, a read-only array) is such a stop: none may appear while scenes with
LOD, contact, grasps, merges batched and self-collision run.
"""

from __future__ import annotations

import importlib
import pkgutil

import pytest

import cloth_lod_ros.sim as sim_package
from cloth_lod_ros.sim import ClothSim, kernels

pytestmark = pytest.mark.skipif(not kernels.available, reason="numba not installed")


def _signatures() -> dict:
    from numba.core.registry import CPUDispatcher
    counts = {}
    for info in pkgutil.iter_modules(sim_package.__path__):
        module = importlib.import_module(f"cloth_lod_ros.sim.{info.name}")
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher):
                counts[f"{info.name}.{name}"] = len(value.signatures)
    return counts


def test_no_kernel_compiles_after_the_warm_up():
    ClothSim.from_scene("hang_two_corners", ["cloth.level=2"])       # warms up, once
    before = _signatures()
    for scene, overrides, steps in (
            ("hang_two_corners", ["cloth.level=5"], 80),
            ("hang_two_corners", ["cloth.level=4", "lod.merge_interval=3"], 40),
            ("grasp_lift", ["cloth.level=4"], 60),
            ("drop_on_sphere", ["cloth.level=4"], 40),
            ("fold_in_half", ["cloth.level=4", "self_collision.enabled=true"], 40)):
        sim = ClothSim.from_scene(scene, overrides)
        for _ in range(steps):
            sim.step()
        after = _signatures()
        assert after == before, {k: v for k, v in after.items() if before.get(k) != v}
