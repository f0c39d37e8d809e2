"""The node's session recording: one bag at a time, never a reason to stop (design §7).

:class:`NodeRecording` owns the :class:`~cloth_lod_ros.bag.recorder.SessionRecorder`
of a running node.  The input threads record received poses, the stepping thread
applied inputs and frames, the request thread opens and finishes bags: the
recorder is swapped in and out as one reference, so no thread waits for another.
A bag that cannot be opened or written is logged and reported (``status``), and
the simulation goes on.
"""

from __future__ import annotations

import time

from ..bag.recorder import SessionRecorder
from ..bag.rosbag import BagError

__all__ = ["NodeRecording"]


class NodeRecording:
    """Args:
        namespace: the node's namespace (prefix of the recorded topics).
        compression: MCAP chunk compression.
        grasp_names, obstacle_names: the scene's grasps and obstacles (their
            pose topics are recorded).
        logger: the node's ROS logger; ``context_ok``: whether ROS logging works.
    """

    def __init__(self, namespace: str, compression: str, grasp_names, logger, context_ok,
                 obstacle_names=()):
        self.namespace, self.compression = namespace, compression
        self.grasp_names = list(grasp_names)
        self.obstacle_names = list(obstacle_names)
        self.logger, self.context_ok = logger, context_ok
        self.recorder: SessionRecorder | None = None
        self.error: str | None = None

    def start(self, path: str, sim, parameters: dict, grid_resolution: int,
              time_ns: int) -> str:
        """Open a bag at ``path`` ('' = a dated name); returns what to tell the caller."""
        if not path:
            path = time.strftime("bags/cloth_lod_%Y%m%d_%H%M%S")
        try:
            recorder = SessionRecorder(path, self.namespace, self.compression,
                                       grasp_names=self.grasp_names,
                                       obstacle_names=self.obstacle_names)
        except BagError as exc:
            self.error = str(exc)
            self.logger.error(f"recording not started: {exc}")
            return self.error
        self.error = None
        if sim.step_count:
            self.logger.warning(
                f"recording starts at step {sim.step_count}: `cloth-lod replay` needs a "
                "recording from the start (record:=true, or call cloth/reset after this)")
        recorder.start(sim, parameters, grid_resolution, time_ns)
        self.recorder = recorder
        self.logger.info(f"recording to {recorder.path}")
        return f"recording to {recorder.path}"

    def stop(self) -> str:
        """Finish the bag (summary and ``metadata.yaml``); returns what to tell the caller."""
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            return "not recording"
        recorder.close()
        if recorder.failed:
            self.error = recorder.failed
            return f"recording failed: {recorder.failed}"
        text = f"recording finished: {recorder.writer.message_count} messages, {recorder.path}"
        if self.context_ok():        # no ROS logging once the context is shut down
            self.logger.info(text)
        else:
            print(f"[cloth_lod_node] {text}", flush=True)
        return text

    def status(self) -> str:
        """``off``, ``on: PATH`` (with dropped frames) or ``failed: REASON``."""
        recorder = self.recorder
        if recorder is not None and recorder.failed:
            self.error = recorder.failed
        if self.error is not None:
            return f"failed: {self.error}"
        if recorder is None:
            return "off"
        dropped = recorder.dropped_frames
        return f"on: {recorder.path}" + (f" ({dropped} frames dropped: disk behind)"
                                         if dropped else "")

    def input(self, sim, kind: str, time_ns: int, **payload) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.record_input(sim, kind, time_ns, **payload)

    def message(self, relative: str, data: bytes) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.record_message(relative, data)

    def frame(self, frames: dict, time_ns: int) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.record_frame(frames, time_ns)
