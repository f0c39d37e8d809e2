"""A compiled hash map from non-negative int64 keys to int64 values.

The 4-8 hierarchy's kernels (:mod:`~cloth_lod_ros.sim.mesh.hierarchy_kernels`)
look up, add and remove edges and split midpoints by their packed vertex
pair several dozen times per split.  numba's typed dict does each through
generic C calls (hashing and key comparison by function pointer): about 40 ns
warm and 85 ns with the caches cold, as they are after a time step.  This
table is one ``(capacity, 2)`` int64 array of (key, value) rows (key
:data:`EMPTY` where free; a probe reads one cache line per slot), with linear probing from a
multiplicative hash, and removal by backward shifting (no tombstones, so a
lookup never walks past more than the run of its own neighbours): 7 ns warm,
24 ns cold for the same operations.

The caller keeps the entry count (the kernels keep it in their counters
array) and grows the table (:func:`grown`, to at most a third full) before
it is half full: probe runs stay short, and every function here may assume
a free slot.  Iteration order has no meaning:
:func:`items` returns the entries sorted by key.
"""

from __future__ import annotations

import numpy as np

from ..runtime import compiled as _compiled

__all__ = ["EMPTY", "new_table", "capacity_for", "build", "grown", "items", "get", "put",
           "remove"]

_jit = _compiled._jit

#: The key of a free slot (keys are non-negative).
EMPTY = -1
#: 2^64 / golden ratio: multiplying by it spreads consecutive keys apart.
_SPREAD = np.uint64(0x9E3779B97F4A7C15)


def capacity_for(entries: int) -> int:
    """The power-of-two capacity that keeps ``entries`` (plus room for a
    few dozen additions) at most a third full."""
    return 1 << int(3 * (int(entries) + 16) - 1).bit_length()


def new_table(capacity: int) -> np.ndarray:
    """An empty ``(capacity, 2)`` int64 table (``capacity`` a power of two)."""
    table = np.zeros((int(capacity), 2), dtype=np.int64)
    table[:, 0] = EMPTY
    return table


@_jit
def _home(key, mask):
    """The slot a key's probe starts from."""
    h = np.uint64(key) * _SPREAD
    h = h ^ (h >> np.uint64(29))
    return np.int64(h & np.uint64(mask))


@_jit
def _slot(table, key):
    """The slot holding ``key``, else the free slot where it would go."""
    mask = table.shape[0] - 1
    i = _home(key, mask)
    while table[i, 0] != key and table[i, 0] != EMPTY:
        i = (i + 1) & mask
    return i


@_jit
def get(table, key, default):
    """The value of ``key``, or ``default``."""
    i = _slot(table, key)
    return table[i, 1] if table[i, 0] == key else default


@_jit
def put(table, key, value):
    """Set ``key`` to ``value``; 1 if the key is new (one more entry), else 0."""
    i = _slot(table, key)
    added = 1 if table[i, 0] == EMPTY else 0
    table[i, 0] = key
    table[i, 1] = value
    return added


@_jit
def remove(table, key):
    """Remove ``key``; 1 if it was there (one entry fewer), else 0.

    The entries after it in its probe run that may not be skipped over any
    more move back into the hole, so every key stays reachable from its home
    slot without passing a free one."""
    mask = table.shape[0] - 1
    hole = _slot(table, key)
    if table[hole, 0] != key:
        return 0
    j = hole
    while True:
        j = (j + 1) & mask
        if table[j, 0] == EMPTY:
            break
        home = _home(table[j, 0], mask)
        # Entry j may move to the hole unless its home lies cyclically in (hole, j].
        if hole <= j:
            stays = hole < home <= j
        else:
            stays = home > hole or home <= j
        if not stays:
            table[hole, 0], table[hole, 1] = table[j, 0], table[j, 1]
            hole = j
    table[hole, 0], table[hole, 1] = EMPTY, 0
    return 1


@_jit
def _fill(table, keys, values):
    """Put every ``(keys[i], values[i])`` into ``table``; the count of new keys."""
    added = 0
    for i in range(keys.shape[0]):
        added += put(table, keys[i], values[i])
    return added


def build(keys: np.ndarray, values: np.ndarray, entries: int | None = None) -> np.ndarray:
    """A table holding ``keys`` -> ``values`` (``(k,)`` int64 each, keys
    distinct and non-negative), sized for ``entries`` (default k)."""
    keys = np.ascontiguousarray(keys, dtype=np.int64).reshape(-1)
    values = np.ascontiguousarray(values, dtype=np.int64).reshape(-1)
    if len(keys) != len(values) or (len(keys) and keys.min() < 0):
        raise ValueError("keys must be non-negative and as many as the values")
    table = new_table(capacity_for(len(keys) if entries is None else entries))
    if _fill(table, keys, values) != len(keys):
        raise ValueError("duplicate keys")
    return table


@_jit
def _entries(table):
    count = 0
    for i in range(table.shape[0]):
        if table[i, 0] != EMPTY:
            count += 1
    out_keys, out_values = np.empty(count, np.int64), np.empty(count, np.int64)
    k = 0
    for i in range(table.shape[0]):
        if table[i, 0] != EMPTY:
            out_keys[k], out_values[k] = table[i, 0], table[i, 1]
            k += 1
    return out_keys, out_values


def items(table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(keys, values)`` of every entry, sorted by key."""
    keys, values = _entries(table)
    order = np.argsort(keys, kind="stable")
    return keys[order], values[order]


def grown(table: np.ndarray, entries: int) -> np.ndarray:
    """``table`` rehashed into the capacity :func:`capacity_for` gives
    ``entries`` (the same table if it is that large already)."""
    capacity = capacity_for(entries)
    if capacity <= table.shape[0]:
        return table
    keys, values = _entries(table)
    out = new_table(capacity)
    _fill(out, keys, values)
    return out
