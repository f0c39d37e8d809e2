"""A re-check right after a LOD decision was carried out decides as a full check.

:meth:`~cloth_lod_ros.sim.lod.policy.LodPolicy.decide` with ``recheck`` (the rounds
after the first of :meth:`~cloth_lod_ros.sim.cloth.ClothSim.adapt`) evaluates
the criterion only on the hinges the previous round changed
(:func:`~cloth_lod_ros.sim.lod.policy.changed_hinges`).  Every such decision must
equal the one the whole criterion gives on the same inputs, in running scenes
(refinement in rounds, merges before them, contacts, grasps, self-collision)
with the compiled kernels and with the numpy reference.  Exact equality by
construction: each comparison is of one implementation with itself (the
kernel setting is the same for both calls), evaluated per hinge on the same
positions, so a hinge's measures are the same numbers whichever other
hinges are evaluated with it.
"""

from __future__ import annotations

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.runtime import compiled as runtime_compiled
from cloth_lod_ros.sim.lod import policy as lod_module
from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48
from cloth_lod_ros.sim.lod.policy import changed_hinges
from cloth_lod_ros.sim.mesh.mesh48 import base_mesh
from cloth_lod_ros.sim.physics.elements_kernels import precompute

pytestmark = pytest.mark.usefixtures("kernels_restored")


def _checked_decide(monkeypatch):
    """Patch decide to make every re-check twice (with and without
    ``recheck``) and compare; returns the list of re-checks seen."""
    seen = []
    original = lod_module.LodPolicy.decide

    def decide(self, *args, **kwargs):
        ours = original(self, *args, **kwargs)
        if kwargs.get("recheck") is not None and not kwargs.get("simplify", True):
            full = original(self, *args, **{**kwargs, "recheck": None})
            assert ours.refine == full.refine
            assert ours.merge == full.merge == []
            seen.append(len(ours.refine))
        return ours

    monkeypatch.setattr(lod_module.LodPolicy, "decide", decide)
    return seen


@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("scene, overrides, steps", [
    # Steps: past the last re-check that refines, with and without the kernels
    # (hang_two_corners: the last re-check of 120 steps is at step 37;
    # grasp_lift: 65 of 80; table_drape: 29 of 60, later ones refine nothing,
    # and steps 40-60 were three quarters of the run, mostly self-collision's
    # re-solves as the drape folds over the table's edge, issue 31).
    ("hang_two_corners", ["cloth.level=5"], 40),
    ("grasp_lift", ["cloth.level=5"], 68),
    ("table_drape", ["cloth.level=5"], 32),
    ("fold_in_half", ["cloth.level=5"], 60),
])
def test_rechecks_decide_as_full_checks(monkeypatch, compiled, scene, overrides, steps):
    if compiled and not runtime_compiled.available:
        pytest.skip("numba not installed")
    runtime_compiled.use(compiled)
    seen = _checked_decide(monkeypatch)
    # decide's re-checks: the rounds on the adopted mesh (the pool rounds'
    # equality with them is test_lod_rounds').
    monkeypatch.setattr(ClothSim, "pool_rounds", False)
    sim = ClothSim.from_scene(scene, overrides)
    for _ in range(steps):
        sim.step()
    assert seen                                  # the scene re-checked
    if scene == "hang_two_corners":
        assert any(seen)                         # and refined on a re-check


def test_changed_hinges_are_those_of_new_triangles_and_moved_particles():
    base = base_mesh(1.0, 1.0, 2, 2)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(base.vertex_count)]), 0.1, 4)
    h.refine_uniform(2, time=0.0)
    mesh, vertex_ids, triangle_ids = h.active_mesh()
    elements = precompute(mesh)
    assert len(changed_hinges(elements, h, vertex_ids, triangle_ids, 1.0, [])) == 0
    h.refine(int(triangle_ids[3]), time=1.0)
    mesh, vertex_ids, triangle_ids = h.active_mesh()
    elements = precompute(mesh)
    born = h.birth[triangle_ids] == 1.0
    expect = np.flatnonzero(born[elements.hinge_triangles].any(axis=1))
    np.testing.assert_array_equal(
        changed_hinges(elements, h, vertex_ids, triangle_ids, 1.0, np.zeros((0, 2))), expect)
    # A merged edge's ends: every hinge at them too.
    ends = vertex_ids[[0, 5]]
    moved = np.isin(vertex_ids[elements.hinge_vertices], ends).any(axis=1)
    np.testing.assert_array_equal(
        changed_hinges(elements, h, vertex_ids, triangle_ids, 1.0, ends.reshape(1, 2)),
        np.flatnonzero(born[elements.hinge_triangles].any(axis=1) | moved))
