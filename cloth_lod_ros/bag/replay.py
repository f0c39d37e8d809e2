"""Re-simulate a recorded session and compare it with the recording (design §7).

:func:`replay` rebuilds the simulator from ``/cloth/session``, applies every
``/cloth/inputs`` event before the step it was applied before in the
recording, and compares each recorded frame with the replayed state: the
``cloth/grid`` samples (the same material points whatever the mesh; float32
as published), the triangle count, and - on the last frame of each segment -
every surface triangle corner of ``cloth/markers`` (float64, bit for bit).

Inputs recorded after the last frame of a segment (the poses that arrive
between the final frame and Ctrl-C, or before a reset) have no recorded result
to be compared with: they are counted, not simulated.
"""

from __future__ import annotations

import json

import numpy as np

from ..messages.frames import grid_uv
from ..messages.markers import TRIANGLE_LIST
from ..sim import ClothSim
from ..sim.scene.config import scene_from_dict
from .analysis import decode, read_session, topic_named
from .rosbag import BagError, BagReader

__all__ = ["replay", "format_replay"]


def _apply(sim, event: dict) -> None:
    kind = event["kind"]
    if kind == "grasp_target":
        sim.set_grasp_target(event["grasp"], event["position"], event.get("orientation"))
    elif kind == "obstacle_target":
        sim.set_obstacle_target(event["obstacle"], event["position"], event.get("orientation"))
    elif kind == "grasp_close":
        sim.close_grasp(event["grasp"])
    elif kind == "grasp_open":
        sim.open_grasp(event["grasp"])
    elif kind == "parameters":
        sim.update_parameters(event["changes"])
    elif kind not in ("pause", "resume"):
        raise BagError(f"unknown input kind {kind!r} at step {event['step_count']}")


def replay(path, progress=None) -> dict:
    """Re-simulate a recorded session and measure how far it is from the recording.

    Returns:
        A JSON-ready dict: per compared frame the simulated time, RMS and max
        distance of the grid samples (m), and whether the triangle count matched;
        overall maxima; ``surface_identical`` per segment (float64 corners of
        the last recorded surface, bit for bit); ``inputs_applied`` and
        ``inputs_after_last_frame`` (inputs no later frame of their segment
        records, so not simulated or compared); ``identical`` when everything
        compared is exactly equal.

    Raises:
        BagError: not a replayable recording (no session, or the recording
            started after the simulation had run).
    """
    with BagReader(path) as reader:
        session = read_session(reader)
        wanted = {t for t in (topic_named(reader, r) for r in (
            "cloth/inputs", "cloth/grid", "cloth/markers", "cloth/lod_stats")) if t}
        messages = list(reader.messages(sorted(wanted)))
    if session.get("start_step_count", 0):
        raise BagError(f"{path}: the recording starts at step {session['start_step_count']} "
                       "of a running simulation; replay needs a recording from the start")
    # Which inputs a later frame of the same segment records the effect of.
    events = [json.loads(decode(m.data, m.type_name).data)
              if m.topic.endswith("cloth/inputs") else None for m in messages]
    is_frame, seen_grid = [], False
    for m in messages:
        seen_grid = seen_grid or m.topic.endswith("cloth/grid")
        is_frame.append(m.topic.endswith("cloth/lod_stats") and seen_grid)
    compared, frame_follows = [False] * len(messages), False
    for i in reversed(range(len(messages))):
        if events[i] is not None and events[i]["kind"] == "reset":
            frame_follows = False
        compared[i] = frame_follows
        frame_follows = frame_follows or is_frame[i]
    resolution = int(session["grid_resolution"])
    sim = ClothSim(scene_from_dict(session["scene"]))
    uv = grid_uv(sim.scene, resolution)
    frames, segments, surface_checks = [], [], []
    last_markers = last_grid = None
    frame_markers = None            # the markers message of the latest compared frame
    inputs_applied = inputs_after_last_frame = 0

    def advance(step_count: int) -> None:
        if step_count < sim.step_count:
            raise BagError(f"recording is not replayable: an input at step {step_count} "
                           f"after step {sim.step_count} (did it start mid-session?)")
        while sim.step_count < step_count:
            sim.step()
            if progress is not None:
                progress(sim)

    def check_surface() -> None:
        """Compare the latest frame's surface corners (float64) bit for bit."""
        if frame_markers is None:
            return
        markers = decode(frame_markers.data, frame_markers.type_name)
        surface = [mk for mk in markers.markers if mk.type == TRIANGLE_LIST]
        replayed = sim.positions[sim.triangles].reshape(-1, 3)
        recorded = np.array([[p.x, p.y, p.z] for p in surface[0].points]) if surface else None
        surface_checks.append(bool(recorded is not None and recorded.shape == replayed.shape
                                   and np.array_equal(recorded, replayed)))

    for m, event, before_a_frame in zip(messages, events, compared):
        if event is not None:
            if event["kind"] == "reset":
                check_surface()
                frame_markers = None
                segments.append(sim.step_count)
                sim = ClothSim(scene_from_dict(event["scene"]))
                uv = grid_uv(sim.scene, resolution)
                continue
            if not before_a_frame:       # nothing recorded shows its effect: not simulated
                inputs_after_last_frame += 1
                continue
            advance(int(event["step_count"]))
            _apply(sim, event)
            inputs_applied += 1
        elif m.topic.endswith("cloth/markers"):
            last_markers = m
        elif m.topic.endswith("cloth/grid"):
            last_grid = m
        elif m.topic.endswith("cloth/lod_stats") and last_grid is not None:
            msg = decode(m.data, m.type_name)
            values = {kv.key: kv.value for kv in msg.status[0].values}
            step_count = int(values["step_count"])
            advance(step_count)
            grid = decode(last_grid.data, last_grid.type_name)
            recorded = np.frombuffer(bytes(grid.data), dtype="<f4").reshape(-1, 3)
            replayed = sim.sample(uv).astype("<f4")
            if recorded.shape != replayed.shape:
                raise BagError(f"{path}: cloth/grid has {len(recorded)} points, the session "
                               f"says {len(replayed)}")
            d = np.linalg.norm(recorded.astype(float) - replayed.astype(float), axis=1)
            frames.append(dict(time=sim.time, rms_m=float(np.sqrt(np.mean(d * d))),
                               max_m=float(d.max()),
                               exact=bool(np.array_equal(recorded, replayed)),
                               triangles_match=int(values["triangles"]) == sim.mesh.triangle_count))
            frame_markers = last_markers
    check_surface()
    rms = [f["rms_m"] for f in frames]
    return dict(bag=str(path), frames=frames, frame_count=len(frames),
                resets=len(segments), inputs_applied=inputs_applied,
                inputs_after_last_frame=inputs_after_last_frame,
                max_distance_m=max((f["max_m"] for f in frames), default=0.0),
                max_rms_m=max(rms, default=0.0),
                all_grid_exact=all(f["exact"] for f in frames),
                all_triangle_counts_match=all(f["triangles_match"] for f in frames),
                surface_identical=surface_checks,
                identical=bool(frames) and all(f["exact"] and f["triangles_match"]
                                               for f in frames) and all(surface_checks))


def format_replay(result: dict) -> str:
    """Text summary of :func:`replay`."""
    frames = result["frames"]
    lines = [f"{result['bag']}: replayed {result['frame_count']} recorded frames "
             f"({result['resets']} reset(s)), {result['inputs_applied']} input(s) applied"]
    if result["inputs_after_last_frame"]:
        lines.append(f"  {result['inputs_after_last_frame']} input(s) came after the last "
                     "recorded frame (of the session or before a reset): no frame shows "
                     "their effect, so they were not compared")
    if frames:
        lines.append(f"  grid distance replayed vs recorded: max {result['max_distance_m']:.3g} m, "
                     f"worst-frame RMS {result['max_rms_m']:.3g} m")
        picks = sorted(set(np.linspace(0, len(frames) - 1, min(len(frames), 6)).astype(int)))
        for i in picks:
            f = frames[i]
            lines.append(f"    t = {f['time']:7.3f} s  RMS {f['rms_m']:.3g} m  max {f['max_m']:.3g} m"
                         f"{'  exact' if f['exact'] else ''}")
    lines.append(f"  triangle counts match: {result['all_triangle_counts_match']}; final surface "
                 f"bit-identical: {result['surface_identical']}")
    lines.append("  IDENTICAL: the replay reproduces the recording bit for bit"
                 if result["identical"] else
                 "  NOT identical (see the distances above)")
    return "\n".join(lines)
