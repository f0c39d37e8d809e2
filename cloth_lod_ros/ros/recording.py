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
from pathlib import Path

from ..bag.recorder import INPUT_BYTES_PER_S, SessionRecorder
from ..bag.rosbag import BagError

__all__ = ["NodeRecording", "MAX_NAME_ATTEMPTS"]

#: Numbered names tried after an existing one (``NAME_2`` ... ``NAME_100``).
MAX_NAME_ATTEMPTS = 100


def _dated_name() -> str:
    """``bags/cloth_lod_<date>_<time>_<milliseconds>`` (local time)."""
    now = time.time()
    return time.strftime("bags/cloth_lod_%Y%m%d_%H%M%S", time.localtime(now)) + \
        f"_{int(now * 1000) % 1000:03d}"


def _taken(path: str) -> bool:
    """Whether a bag may not be written at ``path`` (it exists, and is not an empty
    directory: the rule of :class:`~cloth_lod_ros.bag.rosbag.BagWriter`)."""
    p = Path(path)
    return p.exists() and not (p.is_dir() and not any(p.iterdir()))


def _dropped(recorder) -> str:
    """What a bag left out, for ``status`` and the finishing line ('' if nothing)."""
    parts = []
    if recorder.dropped_frames:
        parts.append(f"{recorder.dropped_frames} frames dropped: disk behind")
    if recorder.dropped_messages:
        parts.append(f"{recorder.dropped_messages} messages dropped: writer queue full")
    if recorder.unrecorded:
        parts.append(f"{recorder.unrecorded} received messages over the "
                     f"{INPUT_BYTES_PER_S // 1000} kB/s input budget not recorded")
    return f" ({'; '.join(parts)})" if parts else ""


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
              time_ns: int) -> tuple[bool, str]:
        """Open a bag at ``path`` ('' = a dated name); returns (started, what to tell
        the caller).  A new bag clears the failure of an earlier one; an existing
        path is never overwritten: the name gets a counter (``_2``, ``_3``, ...)."""
        base = path or _dated_name()
        recorder, error = None, None
        for attempt in range(1, MAX_NAME_ATTEMPTS + 1):
            candidate = base if attempt == 1 else f"{base.rstrip('/')}_{attempt}"
            if _taken(candidate):
                continue
            try:
                recorder = SessionRecorder(candidate, self.namespace, self.compression,
                                           grasp_names=self.grasp_names,
                                           obstacle_names=self.obstacle_names)
                break
            except BagError as exc:
                error = str(exc)
                if not _taken(candidate):       # not a race for the name: give up
                    break
        if recorder is None:
            self.error = error or (f"{base} and {MAX_NAME_ATTEMPTS - 1} numbered names "
                                   "after it exist; a bag is never overwritten")
            self.logger.error(f"recording not started: {self.error}")
            return False, f"recording not started: {self.error}"
        self.error = None
        if sim.step_count:
            self.logger.warning(
                f"recording starts at step {sim.step_count}: `cloth-lod replay` needs a "
                "recording from the start (record:=true, or call cloth/reset after this)")
        recorder.start(sim, parameters, grid_resolution, time_ns)
        self.recorder = recorder
        self.logger.info(f"recording to {recorder.path}")
        return True, f"recording to {recorder.path}"

    def stop(self) -> tuple[bool, str]:
        """Finish the bag (summary and ``metadata.yaml``); returns (whether the
        state is now a good one, what to tell the caller).

        Recording: the bag is finished; ``False`` if it failed (the failure stays in
        :meth:`status` until a new bag starts or ``stop`` is called again).  Not
        recording: ``True`` always, and a failure shown is cleared."""
        recorder, self.recorder = self.recorder, None
        if recorder is None:
            cleared, self.error = self.error, None
            return True, ("not recording" if cleared is None else
                          f"not recording; cleared the failure: {cleared}")
        recorder.close()
        if recorder.failed:
            self.error = recorder.failed
            return False, f"recording failed: {recorder.failed} (bag {recorder.path} kept)"
        text = (f"recording finished: {recorder.writer.message_count} messages, "
                f"{recorder.path}{_dropped(recorder)}")
        if self.context_ok():        # no ROS logging once the context is shut down
            self.logger.info(text)
        else:
            print(f"[cloth_lod_node] {text}", flush=True)
        return True, text

    @property
    def failed(self) -> str | None:
        """Why the recording failed (the bag being written, or the last one), or None."""
        recorder = self.recorder
        if recorder is not None and recorder.failed:
            return recorder.failed
        return self.error

    def status(self) -> str:
        """``off``, ``on: PATH`` (with what was dropped) or ``failed: REASON``."""
        failed = self.failed
        if failed is not None:
            return f"failed: {failed}"
        recorder = self.recorder
        if recorder is None:
            return "off"
        return f"on: {recorder.path}{_dropped(recorder)}"

    def input(self, sim, kind: str, time_ns: int, **payload) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.record_input(sim, kind, time_ns, **payload)

    def message(self, relative: str, data: bytes) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.record_message(relative, data)

    def rejected(self, relative: str, reason: str, **copy) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.record_rejected(relative, reason, **copy)

    def frame(self, frames: dict, time_ns: int) -> None:
        recorder = self.recorder
        if recorder is not None:
            recorder.record_frame(frames, time_ns)
