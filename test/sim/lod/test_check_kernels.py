"""A LOD check without filters, in one compiled call, decides as the staged path.

:func:`~cloth_lod_ros.sim.lod.check_kernels.plain_decision` runs the criterion,
refine order, merge candidates with tests (a)-(d) and merge energies in one
kernel when no filter applies between them.  Every such decision in running
scenes must equal the staged one bit for bit (forced by a filter that lets
everything through): both run the same compiled helpers (lod_kernels'
_criterion, _refine_order, _merge_candidates, _merge_energies) on the same
arrays in one process, and the same numpy product for the gravity term, so
their numbers are the same operations in the same order.  Against the numpy
reference (numpy's arctan2 and tan, not the C library's) the decisions must
agree except within the tolerances of test/tolerances.py of a threshold.
"""

from __future__ import annotations

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.lod import check_kernels
from cloth_lod_ros.sim.runtime import compiled
from cloth_lod_ros.sim.lod import policy as lod_module
from tolerances import assert_lod_decisions_agree

pytestmark = [pytest.mark.skipif(not compiled.available, reason="numba not installed"),
              pytest.mark.usefixtures("kernels_restored")]


def _let_all_through(vertices):
    return np.zeros(len(vertices), dtype=bool)


def _same(a, b):
    assert a.refine == b.refine and a.merge == b.merge
    for name in ("merge_energy", "merge_kinetic", "merge_bound"):
        assert np.asarray(getattr(a, name)).tobytes() == np.asarray(getattr(b, name)).tobytes()


@pytest.mark.parametrize("scene, overrides, steps", [
    ("hang_two_corners", ["cloth.level=5"], 160),
    ("hang_two_corners", ["cloth.level=4", "lod.check_interval=1"], 80),
])
def test_plain_checks_decide_as_the_staged_path(monkeypatch, scene, overrides, steps):
    seen = {"plain": 0, "merged": 0}
    original = lod_module.LodPolicy.decide
    plain = check_kernels.plain_decision

    def counted(*args, **kwargs):
        seen["plain"] += 1
        return plain(*args, **kwargs)

    def decide(self, *args, **kwargs):
        ours = original(self, *args, **kwargs)
        if kwargs.get("supported") is None and kwargs.get("recheck") is None:
            staged = original(self, *args, **{**kwargs, "supported": _let_all_through})
            _same(ours, staged)
            compiled.use(False)
            try:
                reference = original(self, *args, **kwargs)       # the numpy reference
            finally:
                compiled.use(True)
            assert_lod_decisions_agree(ours, reference, self, *args[:7],
                                       lookahead=kwargs.get("lookahead", 0.0))
            seen["merged"] += len(ours.merge)
        return ours

    monkeypatch.setattr(check_kernels, "plain_decision", counted)
    monkeypatch.setattr(lod_module.LodPolicy, "decide", decide)
    sim = ClothSim.from_scene(scene, overrides)
    for _ in range(steps):
        sim.step()
    assert seen["plain"] > 0 and seen["merged"] > 0     # plain checks ran, and merged


def test_filters_take_the_staged_path(monkeypatch):
    """Obstacles (the supported test), grasp detail: no plain decision."""
    calls = []
    monkeypatch.setattr(check_kernels, "plain_decision",
                        lambda *a, **k: calls.append(1))
    sim = ClothSim.from_scene("grasp_lift", ["cloth.level=4"])
    for _ in range(12):
        sim.step()
    assert not calls


def test_plain_decision_declines_without_kernels():
    sim = ClothSim.from_scene("hang_two_corners", ["cloth.level=3"])
    compiled.use(False)
    assert check_kernels.plain_decision(
        sim.hierarchy, sim.elements, sim.vertex_ids, sim.triangle_ids, sim.positions,
        sim.velocities, sim.masses, 0.0, np.zeros(0, np.int64), sim.scene.lod,
        sim.scene.material, np.zeros(3), 0.0, np.zeros(0, np.int64), True) is None
