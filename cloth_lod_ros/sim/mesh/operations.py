"""Mesh operations as values, and the log of those a step made.

``Split(edge)`` bisects the hypotenuse ``edge`` shared by its one or two
triangles; ``Merge(edge)`` removes that edge's midpoint and restores the two
triangles; each is the other's :meth:`~Split.inverse` (paper §5.2-§5.3,
design §4).  :class:`~cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48` applies
them.

:meth:`cloth_lod_ros.sim.cloth.ClothSim.step` keeps every split and merge
its LOD pass makes, so that a step that fails can be undone exactly (the
inverses, in reverse order).  Most steps are not refused, so the compiled
operations (:meth:`~cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48.carry_out`) append
their kernels' ``(n, 3)`` log arrays as they are, and they become
:class:`~cloth_lod_ros.sim.mesh.operations.Split`/``Merge`` values only if the log
is read: a few Python objects per operation less at every LOD pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .hierarchy_kernels import SPLIT

__all__ = ["OperationLog", "Split", "Merge"]


class OperationLog:
    """The operations of a step, in order, read as a list of Split/Merge values.

    ``append``/``extend`` take values (the reference operations);
    :meth:`add_raw` takes a kernels' log, ``(n, 3)`` int64 rows ``kind, left,
    right`` (kind :data:`~cloth_lod_ros.sim.mesh.hierarchy_kernels.SPLIT` or
    ``MERGE``; the array is kept, not copied).
    """

    def __init__(self):
        self._parts: list = []

    def append(self, op) -> None:
        self._parts.append([op])

    def extend(self, ops) -> None:
        self._parts.append(list(ops))

    def add_raw(self, ops: np.ndarray) -> None:
        self._parts.append(ops)

    def values(self) -> list:
        """The Split/Merge values, in order."""
        out = []
        for part in self._parts:
            if isinstance(part, np.ndarray):
                out.extend(Split((a, b)) if kind == SPLIT else Merge((a, b))
                           for kind, a, b in part.tolist())
            else:
                out.extend(part)
        return out

    def __iter__(self):
        return iter(self.values())

    def __reversed__(self):
        return reversed(self.values())

    def __len__(self) -> int:
        return sum(len(part) for part in self._parts)

    def __bool__(self) -> bool:
        return len(self) > 0


@dataclass(frozen=True)
class Split:
    """Bisect the hypotenuse ``edge`` (sorted pool vertex ids) of its block."""

    edge: tuple[int, int]

    def inverse(self) -> "Merge":
        return Merge(self.edge)


@dataclass(frozen=True)
class Merge:
    """Remove the midpoint of ``edge`` and restore the triangles it split."""

    edge: tuple[int, int]

    def inverse(self) -> Split:
        return Split(self.edge)
