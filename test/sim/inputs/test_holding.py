"""What pins and grasps hold after topology changes equals its plain definition.

:meth:`~cloth_lod_ros.sim.inputs.holding.HeldInputs._refresh_held` updates holding patches
with masks over the compact particles; after every adoption of a new mesh (splits,
merges of held particles by script, undo, a refused step's roll-back, steps in
between) its pins and grasps must equal what the ``np.isin``/``np.setdiff1d``
formulation gives from the same previous state.
"""

from __future__ import annotations

import copy

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import scene_from_dict
from cloth_lod_ros.sim.mesh.operations import Merge
from cloth_lod_ros.sim.mesh.topology import MeshError


def held_scene():
    return scene_from_dict({
        "name": "held",
        "cloth": {"width": 1.0, "height": 1.0, "base_blocks": [2, 2], "level": 5},
        "material": {"air_drag": 0.0},
        "pins": [{"name": "a", "uv": [0.0, 1.0], "radius": 0.15},
                 {"name": "b", "uv": [0.5, 1.0], "radius": 0.1},
                 {"name": "c", "uv": [1.0, 1.0]}],
        "grasps": [{"name": "g", "uv": [0.5, 0.5], "width": 0.3}],
        "simulation": {"time_step": 1 / 60, "duration": 1.0},
        "solver": {"method": "direct"},
        "lod": {"enabled": True, "initial_level": 1},
    })


def reference(sim, pins, grasps) -> None:
    """The plain definition, applied to copies of the pins and grasps."""
    ids, x = sim.vertex_ids, sim.state.positions
    for pin in pins:
        pin.vertex = int(np.searchsorted(ids, pin.node))
        if pin.radius > 0 and pin.active(sim.state.time):
            inside = sim._within(pin.uv, pin.radius)
            keep = np.isin(pin.nodes, inside) | (pin.nodes == pin.node)
            pin.nodes, pin.offsets = pin.nodes[keep], pin.offsets[keep]
            new = np.setdiff1d(inside, pin.nodes)
            if len(new):
                pin.hold_more(new, x[np.searchsorted(ids, new)], x[pin.vertex])
        pin.vertices = np.searchsorted(ids, pin.nodes)
    for g in grasps:
        present = np.isin(g.nodes, ids)         # a scripted merge took the rest away
        g.nodes, g.offsets = g.nodes[present], g.offsets[present]
        if g.closed and g.width > 0:
            new = np.setdiff1d(sim._within(g.uv, 0.5 * g.width), g.nodes)
            if len(new):
                g.hold_more(new, x[np.searchsorted(ids, new)])


def checked_sim():
    sim = ClothSim(held_scene())
    sim.close_grasp("g")
    real, count = sim._refresh_held, [0]

    def refresh_and_compare():
        pins, grasps = copy.deepcopy(sim.pins), copy.deepcopy(sim.grasps)
        reference(sim, pins, grasps)
        real()
        for want, got in zip(pins, sim.pins):
            assert want.vertex == got.vertex
            np.testing.assert_array_equal(got.nodes, want.nodes)
            np.testing.assert_array_equal(got.offsets, want.offsets)
            np.testing.assert_array_equal(got.vertices, want.vertices)
        for want, got in zip(grasps, sim.grasps):
            np.testing.assert_array_equal(got.nodes, want.nodes)
            np.testing.assert_array_equal(got.offsets, want.offsets)
        count[0] += 1

    sim._refresh_held = refresh_and_compare
    return sim, count


@settings(max_examples=25, deadline=None)
@given(actions=st.lists(st.tuples(st.sampled_from(
    ["refine", "refine", "merge", "merge_held", "undo", "roll_back", "step", "release"]),
    st.integers(0, 10**6)), min_size=1, max_size=25))
def test_held_patches_equal_their_definition_through_changes(actions):
    sim, count = checked_sim()
    h, done = sim.hierarchy, []
    for kind, k in actions:
        held = set(sim._held_nodes().tolist())
        if kind == "refine":
            tids = h.active_triangles()
            ops = sim.refine(int(tids[k % len(tids)]))
            if ops:
                done.append(ops)
        elif kind in ("merge", "merge_held"):
            # A scripted merge may take a held particle away (the patch lets it go).
            edges = [e for e in h.mergeable_edges()
                     if (h.midpoint[e] in held) == (kind == "merge_held")]
            if edges:
                ops = [Merge(edges[k % len(edges)])]
                sim.apply_mesh_operations(ops)
                done.append(ops)
        elif kind == "undo" and done:
            # The steps since may have refined the children further: then the
            # undo is refused whole and the mesh stays as it was.
            active = h.active_triangles()
            try:
                sim.apply_mesh_operations([op.inverse() for op in reversed(done.pop())])
            except MeshError:
                np.testing.assert_array_equal(h.active_triangles(), active)
        elif kind == "roll_back":
            # A refused step undoes its LOD operations (ClothSim._roll_back).
            before = sim.state.copy()
            tids = h.active_triangles()
            sim._step_operations = sim.refine(int(tids[k % len(tids)]))
            sim._roll_back(before)
            sim._step_operations = None
        elif kind == "step":
            sim.step()
        elif kind == "release":
            sim.release_pin("ab"[k % 2])
        h.check()


def test_refining_inside_patches_adds_held_particles_and_is_checked():
    sim, count = checked_sim()
    before = {p.name: len(p.nodes) for p in sim.pins} | {"g": len(sim.grasp("g").nodes)}
    h = sim.hierarchy
    for _ in range(3):
        for uv in ([0.05, 0.95], [0.5, 0.95], [0.5, 0.5]):
            tids = h.active_triangles()
            centroid = h.uv[h.tri[tids]].mean(axis=1)
            for t in tids[np.linalg.norm(centroid - uv, axis=1) < 0.3]:
                if h.tri_active[t]:
                    sim.refine(int(t))
    assert count[0] > 0
    after = {p.name: len(p.nodes) for p in sim.pins} | {"g": len(sim.grasp("g").nodes)}
    assert after["g"] > before["g"]
    assert after["a"] >= before["a"] and after["b"] >= before["b"]


def test_a_grasp_lets_go_of_a_particle_an_undone_split_removed():
    """Found by the property test above: a split inside the grasp's patch
    made a particle the grasp took; undoing it removed that particle, and the
    grasp kept its id (the next step indexed past the particles)."""
    sim, _ = checked_sim()
    h, done = sim.hierarchy, []
    for k in (4040, 23729):
        tids = h.active_triangles()
        done.append(sim.refine(int(tids[k % len(tids)])))
    grasp = sim.grasps[0]
    taken = grasp.nodes.copy()
    sim.apply_mesh_operations([op.inverse() for op in reversed(done.pop())])
    assert np.isin(grasp.nodes, sim.vertex_ids).all()
    assert len(grasp.nodes) < len(taken)           # it held a particle that is gone
    sim.step()
    assert np.all(np.isfinite(sim.positions))
