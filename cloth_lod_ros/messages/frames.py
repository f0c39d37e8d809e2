"""One frame of the node's outputs, built from a simulator (design §6).

:class:`FrameBuilder` turns one simulator state into the CDR bytes of the node's
outputs (``cloth/markers``, ``cloth/points``, ``cloth/grid``, ``cloth/lod_stats``).
The node publishes them and the recorder writes them, headless or live, so a bag
written headless and one written by the node hold the same messages.
"""

from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from ..sim.mesh.sampling import material_grid
from .markers import (CUBE, DELETEALL, MarkerSpec, cloth_markers, obstacle_markers,
                      serialize_marker_array, serialize_point_cloud, unique_edges)

__all__ = ["FrameBuilder", "grid_uv", "standard_diagnostics"]


def grid_uv(scene, resolution: int) -> np.ndarray:
    """``(resolution², 2)`` material points (m) of ``cloth/grid``, row-major in v then u."""
    return material_grid(scene.cloth.width, scene.cloth.height, resolution)


class FrameBuilder:
    """Builds one frame of outputs from a simulator; keeps the per-step history
    between frames so ``cloth/lod_stats`` carries every step's timings.

    Args:
        frame_id: frame of every header.
        grid_resolution: points per side of ``cloth/grid``.
        colour_by, wireframe: marker options (see :func:`cloth_markers`).
    """

    def __init__(self, frame_id: str = "world", grid_resolution: int = 21,
                 colour_by: str = "level", wireframe: bool = True):
        self.frame_id = frame_id
        self.grid_resolution = int(grid_resolution)
        self.colour_by = colour_by
        self.wireframe = wireframe
        self.reset()

    def reset(self) -> None:
        """Forget the previous simulator (call after a reset)."""
        self._edges_key = None
        self._edges = None
        self._marker_count = 0
        self._next_step = 0
        self.total_refines = 0
        self.total_merges = 0
        self._grid_uv = None

    def build(self, sim, stamp: tuple, values: dict | None = None,
              level: int | None = None, message: str = "running") -> dict:
        """CDR bytes of every output topic for the current state.

        Args:
            sim: the :class:`~cloth_lod_ros.sim.ClothSim`.
            stamp: ``(sec, nanosec)`` of the headers.
            values: extra ``lod_stats`` key/values (strings), e.g. the real-time factor.
            level, message: diagnostic level and message (default: OK, or WARN
                when the last linear solve did not converge).

        Returns:
            ``{relative topic: bytes}`` for the four output topics.
        """
        key = (id(sim.mesh), sim.mesh.triangle_count)
        if key != self._edges_key:           # topology changed: recompute the wireframe edges
            self._edges = unique_edges(sim.triangles, sim.triangle_levels)
            self._edges_key = key
        grasp_points = [g.position for g in sim.grasps if g.closed]
        specs = cloth_markers(sim.positions, sim.triangles, sim.triangle_levels, sim.max_level,
                              self.frame_id, stamp, grasp_points=np.array(grasp_points),
                              colour_by=self.colour_by, wireframe=self.wireframe,
                              edges=self._edges)
        count = len(specs)
        if count < self._marker_count:            # a marker went away: clear stale ones
            specs.insert(0, MarkerSpec("", 0, CUBE, self.frame_id, stamp, action=DELETEALL))
        self._marker_count = count
        specs += obstacle_markers(sim.obstacle_configs(), self.frame_id, stamp)   # where they are now
        if self._grid_uv is None:
            self._grid_uv = grid_uv(sim.scene, self.grid_resolution)
        return {
            "cloth/markers": serialize_marker_array(specs),
            "cloth/points": serialize_point_cloud(sim.positions, self.frame_id, stamp),
            "cloth/grid": serialize_point_cloud(sim.sample(self._grid_uv), self.frame_id,
                                                stamp, height=self.grid_resolution),
            "cloth/lod_stats": serialize_message(
                self.diagnostics(sim, stamp, values or {}, level, message)),
        }

    def diagnostics(self, sim, stamp: tuple, values: dict, level=None,
                    message: str = "running") -> DiagnosticArray:
        """The ``cloth/lod_stats`` message.

        Besides the last step's :class:`~cloth_lod_ros.sim.StepStats` it holds
        ``step_count`` (steps since start or reset), running ``total_refines``
        and ``total_merges``, and ``recent_step_ms``/``recent_lod_ms``/
        ``recent_solve_ms``/``recent_cg_iterations``/``recent_substeps``/
        ``recent_smallest_step_s``/``recent_newton_iterations``: every step
        since the previous message, space-separated, so analysis sees each
        step; ``integrator`` and ``error_tolerance_m`` name the time stepping
        (a step advances one frame, ``simulation.time_step``, in ``substeps``
        integrator steps, the smallest ``smallest_step`` s long).
        """
        recent = [s for s in sim.stats if s.step_index >= self._next_step]
        self._next_step = sim.step_count
        self.total_refines += sum(s.refines for s in recent)
        self.total_merges += sum(s.merges for s in recent)
        last = sim.stats[-1] if sim.stats else None
        entries = {"sim_time_s": repr(float(sim.time)), "step_count": str(sim.step_count),
                   "particles": str(sim.mesh.vertex_count),
                   "triangles": str(sim.mesh.triangle_count),
                   "triangles_per_level": " ".join(
                       str(c) for c in np.bincount(sim.triangle_levels,
                                                   minlength=sim.max_level + 1)),
                   "total_refines": str(self.total_refines),
                   "total_merges": str(self.total_merges),
                   "recent_step_ms": " ".join(f"{s.step_ms:.4f}" for s in recent),
                   "recent_lod_ms": " ".join(f"{s.lod_ms:.4f}" for s in recent),
                   "recent_solve_ms": " ".join(f"{s.solve_ms:.4f}" for s in recent),
                   "recent_cg_iterations": " ".join(str(s.cg_iterations) for s in recent),
                   "integrator": sim.scene.simulation.integrator,
                   "error_tolerance_m": repr(float(sim.stepper.tolerance)),
                   "recent_substeps": " ".join(str(s.substeps) for s in recent),
                   "recent_smallest_step_s": " ".join(f"{s.smallest_step:.6g}"
                                                      for s in recent),
                   "recent_newton_iterations": " ".join(str(s.newton_iterations)
                                                        for s in recent)}
        entries.update(values)
        if last is not None:
            for name, value in last.as_dict().items():
                if name not in ("triangles_per_level", "time"):
                    entries[name] = str(value)
        if level is None:
            level = DiagnosticStatus.OK
            if last is not None and not last.converged:
                level, message = DiagnosticStatus.WARN, "linear solve did not converge"
        status = DiagnosticStatus(name="cloth_lod: simulation", hardware_id=sim.scene.name,
                                  level=level, message=message,
                                  values=[KeyValue(key=k, value=str(v))
                                          for k, v in entries.items()])
        sec, nanosec = stamp
        header = Header(frame_id=self.frame_id)
        header.stamp.sec, header.stamp.nanosec = int(sec), int(nanosec)
        return DiagnosticArray(header=header, status=[status])


def standard_diagnostics(name: str, hardware_id: str, level: int, message: str,
                         values: dict, stamp: tuple) -> bytes:
    """CDR bytes of a ``/diagnostics`` message as ``diagnostic_updater`` publishes it.

    One status named ``name`` ("<node>: <task>"); ``values`` maps keys to
    numbers (rendered with ``repr`` so tools can plot them) or short strings.
    """
    status = DiagnosticStatus(
        name=name, hardware_id=hardware_id, level=bytes([int(level)]), message=message,
        values=[KeyValue(key=k, value=repr(float(v)) if isinstance(v, (int, float, np.number))
                         and not isinstance(v, bool) else str(v)) for k, v in values.items()])
    header = Header()
    header.stamp.sec, header.stamp.nanosec = int(stamp[0]), int(stamp[1])
    return serialize_message(DiagnosticArray(header=header, status=[status]))
