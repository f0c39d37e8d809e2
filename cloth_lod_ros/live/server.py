"""A Foxglove WebSocket server publishing a running simulator (``foxglove-sdk``).

:class:`LiveView` starts the SDK's server (``foxglove.start_server``) on its own
``foxglove.Context`` and publishes, on each :meth:`LiveView.publish`:

============================  ===========================  ==============================
topic                         schema (encoding)            content
============================  ===========================  ==============================
``/cloth/mesh``               foxglove.SceneUpdate (pb)    surface, one colour per level
``/cloth/wireframe``          foxglove.SceneUpdate (pb)    edges, darker level colours
``/cloth/obstacles``          foxglove.SceneUpdate (pb)    obstacles at their current poses
``/cloth/grasps``             foxglove.SceneUpdate (pb)    grip points and targets
``/tf``                       foxglove.FrameTransforms     frames ``obstacle/<name>``,
                                                           ``grasp/<name>``
``/cloth/lod_stats``          JSON (JSON Schema)           numbers for the Plot panel
============================  ===========================  ==============================

A channel nobody subscribes to costs nothing: its message is not built.  The
protocol is Foxglove's WebSocket protocol (subprotocol ``foxglove.sdk.v1`` in
this SDK, the framing of https://github.com/foxglove/ws-protocol/blob/main/docs/spec.md).
"""

from __future__ import annotations

import math
import socket
import time

__all__ = ["LiveView", "LiveViewError", "require_foxglove", "INSTALL_HINT", "DEFAULT_PORT",
           "TOPICS"]

INSTALL_HINT = ("the live view needs foxglove-sdk: install the viewer extra: "
                "pip install '.[viewer]' (in the repository; or pip install foxglove-sdk)")
DEFAULT_PORT = 8765             # Foxglove's usual WebSocket port
MAX_RATE = 60.0                 # Hz, most messages per topic a viewer is sent
BACKLOG = 64                    # messages queued per slow client before the oldest drop
TOPICS = ("/cloth/mesh", "/cloth/wireframe", "/cloth/obstacles", "/cloth/grasps", "/tf",
          "/cloth/lod_stats")
_LOCAL = {"127.0.0.1", "localhost", "::1"}


class LiveViewError(OSError):
    """The live view cannot start: foxglove-sdk is missing, or the address is taken."""


def require_foxglove():
    """The ``foxglove`` module, or :class:`LiveViewError` saying how to install it."""
    try:
        import foxglove
    except ImportError as exc:
        raise LiveViewError(INSTALL_HINT) from exc
    return foxglove


class LiveView:
    """Serves a running :class:`~cloth_lod_ros.sim.ClothSim` to Foxglove.

    Args:
        host: address to listen on (``127.0.0.1``: this machine only;
            ``0.0.0.0``: every interface, to watch from another machine).
        port: TCP port; 0 lets the system choose a free one (see :attr:`port`).
        frame_id: frame of every entity (the node's ``frame_id``).
        max_rate: most frames per second sent (Hz); :meth:`publish` calls
            closer together are skipped.

    Raises:
        LiveViewError: foxglove-sdk is not installed, or the port cannot be bound.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 frame_id: str = "world", name: str = "cloth_lod", max_rate: float = MAX_RATE):
        fox = require_foxglove()
        from foxglove.messages import FrameTransforms, SceneUpdate

        from . import scene
        self._scene = scene
        self.frame_id = frame_id
        self.host = host
        self.min_interval = 1.0 / max_rate
        self._context = fox.Context()
        schema = SceneUpdate.get_schema()
        self._channels = {
            topic: fox.Channel(topic, schema=schema, message_encoding="protobuf",
                               context=self._context)
            for topic in ("/cloth/mesh", "/cloth/wireframe", "/cloth/obstacles",
                          "/cloth/grasps")}
        self._channels["/tf"] = fox.Channel("/tf", schema=FrameTransforms.get_schema(),
                                            message_encoding="protobuf",
                                            context=self._context)
        self._channels["/cloth/lod_stats"] = fox.Channel(
            "/cloth/lod_stats", schema=scene.LOD_STATS_SCHEMA, context=self._context)
        try:
            self.server = fox.start_server(name=name, host=host, port=int(port),
                                           context=self._context,
                                           message_backlog_size=BACKLOG)
        except RuntimeError as exc:
            raise LiveViewError(
                f"cannot serve the live view on {host}:{port}: {exc} (another program, or "
                "another cloth-lod, may use the port: choose another one)") from exc
        self.port = int(self.server.port)
        self._last_publish = -math.inf
        self._sim = None
        self._edges_key = None
        self._edges = None

    # -- addresses ---------------------------------------------------------------
    @property
    def url(self) -> str:
        """The WebSocket URL a viewer on this machine (or, listening on every
        interface, another one) opens."""
        if self.host in _LOCAL:
            host = "localhost"
        elif self.host in ("0.0.0.0", "::", ""):
            host = socket.gethostname()
        else:
            host = self.host
        return f"ws://{host}:{self.port}"

    def instructions(self) -> str:
        """What to open, for a log line."""
        lines = [f"Foxglove live view at {self.url}: in the Foxglove app (desktop, or "
                 "https://app.foxglove.dev in a browser) choose Open connection -> "
                 f"Foxglove WebSocket -> {self.url}",
                 "  3D panel: /cloth/mesh (coloured by level), /cloth/wireframe, "
                 f"/cloth/obstacles, /cloth/grasps in frame '{self.frame_id}'; Plot panel: "
                 "/cloth/lod_stats.triangles, .triangles_per_level[N], .step_ms, .lod_share"]
        if self.host in ("0.0.0.0", "::", ""):
            lines.append("  listening on every interface: from another machine use "
                         f"ws://<this machine's address>:{self.port}")
        return "\n".join(lines)

    # -- publishing ----------------------------------------------------------------
    def has_viewers(self) -> bool:
        """Whether some client subscribes to at least one topic."""
        return any(ch.has_sinks() for ch in self._channels.values())

    def _recent(self, sim) -> list:
        """The step statistics since the previous call (all of them after a new
        simulator, e.g. after a reset), and the running refine/merge totals."""
        if sim is not self._sim:
            self._sim, self._next_step, self._totals = sim, 0, (0, 0)
            self._edges_key = None
        recent = []
        for s in reversed(sim.stats):
            if s.step_index < self._next_step:
                break
            recent.append(s)
        recent.reverse()
        self._next_step = sim.step_count
        self._totals = (self._totals[0] + sum(s.refines for s in recent),
                        self._totals[1] + sum(s.merges for s in recent))
        return recent

    def publish(self, sim, stamp_ns: int | None = None, values: dict | None = None,
                force: bool = False) -> bool:
        """Send the simulator's current state to every subscribed topic.

        Args:
            sim: the :class:`~cloth_lod_ros.sim.ClothSim`.
            stamp_ns: entity timestamps, ns (default: now, wall clock).
            values: extra ``/cloth/lod_stats`` fields (e.g. the node's
                ``real_time_factor``); those that are not numbers are left out.
            force: publish even within ``1 / max_rate`` of the previous frame.

        Returns:
            Whether a frame was sent (False: too soon, or nobody watches).
        """
        now = time.monotonic()
        if not force and now - self._last_publish < self.min_interval:
            return False
        recent = self._recent(sim)
        if not self.has_viewers():
            return False
        self._last_publish = now
        log_time = time.time_ns()
        stamp = log_time if stamp_ns is None else int(stamp_ns)
        s, ch, fid = self._scene, self._channels, self.frame_id
        if ch["/cloth/mesh"].has_sinks():
            ch["/cloth/mesh"].log(s.scene_update(encoded=[s.cloth_entity(
                sim.positions, sim.triangles, sim.triangle_levels, sim.max_level, fid,
                stamp)]), log_time=log_time)
        if ch["/cloth/wireframe"].has_sinks():
            edges, edge_levels = self._mesh_edges(sim)
            ch["/cloth/wireframe"].log(s.scene_update(encoded=[s.wireframe_entity(
                sim.positions, edges, edge_levels, sim.max_level, fid, stamp)]),
                log_time=log_time)
        obstacles = sim.obstacle_configs()              # where they are now
        if ch["/cloth/obstacles"].has_sinks():
            ch["/cloth/obstacles"].log(s.scene_update(s.obstacle_entities(
                obstacles, fid, stamp)), log_time=log_time)
        if ch["/cloth/grasps"].has_sinks():
            ch["/cloth/grasps"].log(s.scene_update(s.grasp_entities(sim.grasps, fid, stamp)),
                                    log_time=log_time)
        if ch["/tf"].has_sinks():
            ch["/tf"].log(s.frame_transforms(obstacles, sim.grasps, fid, stamp).encode(),
                          log_time=log_time)
        if ch["/cloth/lod_stats"].has_sinks():
            stats = s.lod_stats(sim, recent, self._totals)
            stats.update(_numbers(values or {}))
            ch["/cloth/lod_stats"].log(stats, log_time=log_time)
        return True

    def _mesh_edges(self, sim):
        """Unique edges and their levels, recomputed when the triangles change."""
        from ..messages.markers import unique_edges
        key = (len(sim.triangles), hash(sim.triangles.tobytes()),
               hash(sim.triangle_levels.tobytes()))
        if key != self._edges_key:
            self._edges = unique_edges(sim.triangles, sim.triangle_levels)
            self._edges_key = key
        return self._edges

    def close(self) -> None:
        """Stop the server (viewers see the connection close)."""
        self.server.stop()


def _numbers(values: dict) -> dict:
    """The entries of ``values`` that are finite numbers (strings parsed), as floats."""
    out = {}
    for key, value in values.items():
        if isinstance(value, bool):
            continue
        try:
            number = float(value)
        except (TypeError, ValueError):
            continue
        if math.isfinite(number):
            out[key] = number
    return out
