"""The kernels' int64 hash table (:mod:`cloth_lod_ros.sim.mesh.int_table`) behaves
as a Python dict under random insertions, updates and removals, across growth."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.sim.mesh import int_table
from cloth_lod_ros.sim.runtime import compiled

pytestmark = pytest.mark.skipif(not compiled.available, reason="numba not installed")


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), key_range=st.sampled_from([8, 64, 4096, 2**62]))
def test_random_operations_match_a_dict(seed, key_range):
    rng = np.random.default_rng(seed)
    table, count, reference = int_table.build(np.zeros(0, np.int64), np.zeros(0, np.int64)), 0, {}
    for _ in range(600):
        if 2 * (count + 1) > len(table):            # the callers' rule: grow before half full
            table = int_table.grown(table, count)
            assert 3 * (count + 16) <= len(table)
        key = int(rng.integers(key_range))
        roll = rng.random()
        if roll < 0.55:
            value = int(rng.integers(-2**40, 2**40))
            added = int_table.put(table, key, value)
            assert added == (key not in reference)
            reference[key] = value
            count += added
        elif roll < 0.9:
            # Removing a key only some keys collide with exercises the backward shift.
            if reference and rng.random() < 0.7:
                key = list(reference)[int(rng.integers(len(reference)))]
            removed = int_table.remove(table, key)
            assert removed == (key in reference)
            reference.pop(key, None)
            count -= removed
        assert int_table.get(table, key, -7) == reference.get(key, -7)
        # Every key stays reachable (no hole left inside a probe run).
        for k, v in list(reference.items())[:20]:
            assert int_table.get(table, k, -7) == v
    keys, values = int_table.items(table)
    assert keys.tolist() == sorted(reference)
    assert values.tolist() == [reference[k] for k in sorted(reference)]
    assert count == len(reference)


def test_build_rejects_duplicate_and_negative_keys():
    with pytest.raises(ValueError, match="duplicate"):
        int_table.build(np.array([3, 3]), np.array([1, 2]))
    with pytest.raises(ValueError, match="non-negative"):
        int_table.build(np.array([-1]), np.array([1]))


def test_a_growing_hierarchy_grows_its_tables():
    """Refining a small base far past its first tables' size: the kernels
    ask for room (NEED_INDEX), get it and carry on to the reference's mesh."""
    from cloth_lod_ros.sim.mesh.hierarchy import Hierarchy48
    from cloth_lod_ros.sim.mesh.mesh48 import base_mesh
    base = base_mesh(1.0, 1.0, 1, 1)
    h = Hierarchy48(base, np.column_stack([base.uv, np.zeros(len(base.uv))]), 0.1, 6)
    first = len(h._kernel_index().edges)
    h.refine_uniform(6)
    assert len(h._kernel_index().edges) > first
    assert h._kernel_index().edge_count == len(h._edges)
    h.check()
