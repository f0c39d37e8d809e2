"""The operation log of a step: read as Split/Merge values, it undoes the step.

:class:`~cloth_lod_ros.sim.mesh.operations.OperationLog` keeps the compiled operations'
raw logs and makes them values only when read; it must read as the list of
values the operations would have appended, and a refused step must still be
undone exactly through it.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim, SimulationError
from cloth_lod_ros.sim.runtime import compiled as runtime_compiled
from cloth_lod_ros.sim.mesh.operations import Merge, Split
from cloth_lod_ros.sim.mesh.operations import OperationLog

pytestmark = pytest.mark.usefixtures("kernels_restored")


def test_a_log_reads_as_the_values_in_order():
    log = OperationLog()
    assert not log and len(log) == 0 and list(log) == []
    log.append(Split((1, 2)))
    log.add_raw(np.array([[0, 3, 4], [1, 5, 6]], dtype=np.int64))
    log.extend([Merge((7, 8))])
    log.add_raw(np.zeros((0, 3), dtype=np.int64))
    expect = [Split((1, 2)), Split((3, 4)), Merge((5, 6)), Merge((7, 8))]
    assert log and len(log) == 4
    assert list(log) == expect == log.values()
    assert list(reversed(log)) == expect[::-1]


@pytest.mark.parametrize("compiled", [True, False])
def test_carry_out_logs_the_same_operations_either_way(compiled):
    if compiled and not runtime_compiled.available:
        pytest.skip("numba not installed")
    runtime_compiled.use(compiled)
    sim = ClothSim.from_scene("hang_two_corners", ["cloth.level=5"])
    for _ in range(8):
        sim.step()
    h = sim.hierarchy
    tids = h.active_triangles()
    decision = copy.deepcopy(sim.lod_policy).decide(
        h, sim.elements, sim.vertex_ids, sim.triangle_ids, sim.positions, sim.velocities,
        sim.masses, sim.time, sim._held_nodes())
    decision.refine = list(decision.refine) + [int(t) for t in tids[::7]]
    logs = []
    for log in ([], OperationLog()):
        other = copy.deepcopy(h)
        sim.lod_policy.apply(other, decision, sim.time, log=log)
        logs.append(list(log))
    assert logs[0] == logs[1] and logs[0]


def test_a_refused_step_undoes_its_mesh_operations_exactly():
    sim = ClothSim.from_scene("hang_two_corners", ["cloth.level=5"])
    sim.step()                      # check 0: refines the flat start
    for _ in range(3):
        sim.step()
    mesh_before = (sim.vertex_ids.copy(), sim.triangle_ids.copy(), sim.mesh.triangles.copy())
    x_before = sim.positions.copy()
    version = sim.hierarchy.version
    advance = sim.stepper.advance

    def failing(*args, **kwargs):
        raise SimulationError("injected failure; step refused")
    sim.stepper.advance = failing
    with pytest.raises(SimulationError):
        sim.step()                  # a check step: its LOD pass changes the mesh, then fails
    assert sim.hierarchy.version != version          # it did change it, and undid it
    for a, b in zip(mesh_before, (sim.vertex_ids, sim.triangle_ids, sim.mesh.triangles)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(sim.positions, x_before)
    sim.stepper.advance = advance
    sim.step()
