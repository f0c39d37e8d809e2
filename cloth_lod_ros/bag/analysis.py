"""Analyse recorded sessions (design §7).

* :func:`analyze`: step-time statistics, real-time factor, mesh size and LOD
  activity from ``cloth/lod_stats`` (whose ``recent_*`` fields carry every step),
  plus PNG plots.
* :func:`message_class`, :func:`read_session`, :func:`topic_named`: what
  :mod:`~cloth_lod_ros.bag.replay` and the player share.

Messages are decoded with rclpy's deserializer; nothing here needs a running ROS graph.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .rosbag import BagError, BagReader

__all__ = ["analyze", "format_analysis", "plot_analysis", "read_session", "message_class",
           "decode", "topic_named"]


def message_class(type_name: str):
    """The rclpy message class of ``pkg/msg/Type``.

    Raises:
        BagError: the interface package is not installed.
    """
    import importlib
    package, kind, name = type_name.split("/")
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError):
        raise BagError(f"message type {type_name} is not installed") from None


def decode(data: bytes, type_name: str):
    """Deserialise CDR ``data`` of ROS type ``pkg/msg/Type`` into its rclpy message."""
    from rclpy.serialization import deserialize_message
    return deserialize_message(data, message_class(type_name))


def topic_named(reader: BagReader, relative: str) -> str | None:
    """The recorded topic ending in ``relative`` (any namespace), or None."""
    matches = [t for t in reader.topics if t == "/" + relative or t.endswith("/" + relative)]
    return matches[0] if matches else None


def read_session(reader: BagReader) -> dict:
    """The JSON of the bag's ``/cloth/session`` message.

    Raises:
        BagError: no session message (not a cloth_lod_ros recording).
    """
    topic = topic_named(reader, "cloth/session")
    if topic is not None:
        for m in reader.messages([topic]):
            try:
                return json.loads(decode(m.data, m.type_name).data)
            except (ValueError, TypeError) as exc:
                raise BagError(f"{reader.path}: unreadable session message ({exc})") from None
    raise BagError(f"{reader.path}: no cloth/session message; not a cloth_lod_ros recording")


def _numbers(text: str, kind=float) -> list:
    return [kind(x) for x in text.split()] if text else []


@dataclass
class _Frame:
    time_ns: int
    values: dict


def _stats_frames(reader: BagReader) -> list[_Frame]:
    topic = topic_named(reader, "cloth/lod_stats")
    if topic is None:
        raise BagError(f"{reader.path}: no cloth/lod_stats topic")
    frames = []
    for m in reader.messages([topic]):
        msg = decode(m.data, m.type_name)
        if msg.status:
            frames.append(_Frame(m.time_ns, {kv.key: kv.value for kv in msg.status[0].values}))
    if not frames:
        raise BagError(f"{reader.path}: cloth/lod_stats holds no messages")
    return frames


def analyze(path) -> dict:
    """Summary of a recorded session.

    Returns:
        A JSON-ready dict: ``bag`` (path, size, duration, message counts per topic),
        ``steps`` (count, simulated seconds, step/LOD/solve ms statistics, CG
        iterations), ``real_time_factor`` (overall and percentiles over the
        publication intervals), ``mesh`` (triangle counts, final count per level),
        ``lod`` (refine/merge totals), ``segments`` (resets split a session), and
        ``series`` (per-frame and per-step arrays used by :func:`plot_analysis`).
    """
    with BagReader(path) as reader:
        session = read_session(reader)
        frames = _stats_frames(reader)
        topics = {t: info.message_count for t, info in reader.topics.items()}
        size = reader.mcap_path.stat().st_size
        bag = dict(path=str(path), bytes=size, message_count=reader.message_count,
                   duration_s=(reader.end_ns - reader.start_ns) * 1e-9, topics=topics)
    h = float(session["scene"]["simulation"]["time_step"])
    step_ms, lod_ms, solve_ms, cg, step_time = [], [], [], [], []
    frame_time, frame_wall, triangles, per_level, rtf_series, rtf_time = [], [], [], [], [], []
    segments, refines, merges = 1, 0, 0
    sim_seconds = wall_seconds = 0.0
    previous = None
    for f in frames:
        v = f.values
        count = int(v.get("step_count", 0))
        sim_time = float(v.get("sim_time_s", "nan"))
        wall = float(v.get("wall_time_s", "nan"))
        if previous is not None and count < int(previous.get("step_count", 0)):
            segments += 1                          # a reset: totals restart
            refines += int(previous.get("total_refines", 0))
            merges += int(previous.get("total_merges", 0))
            previous = None
        recent = _numbers(v.get("recent_step_ms", ""))
        step_ms += recent
        lod_ms += _numbers(v.get("recent_lod_ms", ""))
        solve_ms += _numbers(v.get("recent_solve_ms", ""))
        cg += _numbers(v.get("recent_cg_iterations", ""), int)
        step_time += [sim_time - h * (len(recent) - 1 - i) for i in range(len(recent))]
        frame_time.append(sim_time)
        frame_wall.append(wall)
        triangles.append(int(v.get("triangles", 0)))
        per_level.append(_numbers(v.get("triangles_per_level", ""), int))
        if previous is not None:
            d_sim = sim_time - float(previous["sim_time_s"])
            d_wall = wall - float(previous.get("wall_time_s", "nan"))
            if d_wall > 0 and math.isfinite(d_wall):
                sim_seconds += d_sim
                wall_seconds += d_wall
                rtf_series.append(d_sim / d_wall)
                rtf_time.append(sim_time)
        previous = v
    refines += int(previous.get("total_refines", 0)) if previous else 0
    merges += int(previous.get("total_merges", 0)) if previous else 0
    steps = np.array(step_ms)

    def stats(a):
        a = np.asarray(a, float)
        if not len(a):
            return {}
        return dict(mean=float(a.mean()), p50=float(np.percentile(a, 50)),
                    p90=float(np.percentile(a, 90)), p99=float(np.percentile(a, 99)),
                    max=float(a.max()))

    levels = max((len(p) for p in per_level), default=0)
    per_level_array = np.array([p + [0] * (levels - len(p)) for p in per_level])
    rtf = np.array(rtf_series)
    return dict(
        bag=bag, scene=session["scene"]["name"], time_step=h, segments=segments,
        package_version=session.get("package_version"),
        steps=dict(count=len(steps), simulated_s=len(steps) * h, step_ms=stats(steps),
                   lod_ms=stats(lod_ms), solve_ms=stats(solve_ms),
                   lod_share=float(np.sum(lod_ms) / steps.sum()) if steps.sum() else 0.0,
                   solve_share=float(np.sum(solve_ms) / steps.sum()) if steps.sum() else 0.0,
                   cg_iterations=stats(cg)),
        real_time_factor=dict(overall=sim_seconds / wall_seconds if wall_seconds else None,
                              **{k: v for k, v in stats(rtf).items() if k != "max"}),
        mesh=dict(triangles_min=min(triangles), triangles_mean=float(np.mean(triangles)),
                  triangles_max=max(triangles), final_per_level=per_level[-1]),
        lod=dict(refines=refines, merges=merges),
        series=dict(frame_time=frame_time, frame_wall=frame_wall, triangles=triangles,
                    per_level=per_level_array.tolist(), step_time=step_time,
                    step_ms=step_ms, lod_ms=lod_ms, solve_ms=solve_ms,
                    rtf_time=rtf_time, rtf=rtf_series))


def format_analysis(result: dict) -> str:
    """Text summary of :func:`analyze`."""
    b, s, r, m = result["bag"], result["steps"], result["real_time_factor"], result["mesh"]
    lines = [f"{b['path']}: scene {result['scene']}, {b['message_count']} messages, "
             f"{b['bytes'] / 1e6:.2f} MB, {b['duration_s']:.2f} s of log time, "
             f"{result['segments']} segment(s)"]
    for topic, count in sorted(b["topics"].items()):
        lines.append(f"  {topic:32s} {count:7d}")
    st = s["step_ms"]
    if st:
        lines.append(f"  steps: {s['count']} ({s['simulated_s']:.2f} s simulated, "
                     f"h = {result['time_step']:.4g} s)")
        lines.append(f"  step time ms: mean {st['mean']:.2f}  p50 {st['p50']:.2f}  "
                     f"p90 {st['p90']:.2f}  p99 {st['p99']:.2f}  max {st['max']:.2f}")
        lines.append(f"  LOD share {100 * s['lod_share']:.1f} %, solve share "
                     f"{100 * s['solve_share']:.1f} %, CG iterations mean "
                     f"{s['cg_iterations']['mean']:.1f} max {s['cg_iterations']['max']:.0f}")
    if r.get("overall") is not None:
        lines.append(f"  real-time factor: {r['overall']:.3f} overall, per interval "
                     f"p50 {r['p50']:.3f}  p90 {r['p90']:.3f}")
    lines.append(f"  triangles: min {m['triangles_min']}  mean {m['triangles_mean']:.0f}  "
                 f"max {m['triangles_max']}; final per level {m['final_per_level']}")
    lines.append(f"  LOD operations: {result['lod']['refines']} refines, "
                 f"{result['lod']['merges']} merges")
    return "\n".join(lines)


def plot_analysis(result: dict, png: Path) -> Path:
    """Three panels over simulated time: triangles by level (stacked), step /
    LOD / solve time per step, real-time factor per publication interval."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    s = result["series"]
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    per_level = np.array(s["per_level"]).T
    if per_level.size:
        colours = plt.cm.viridis(np.linspace(0, 1, len(per_level)))
        axes[0].stackplot(s["frame_time"], per_level, colors=colours,
                          labels=[f"level {k}" for k in range(len(per_level))], step="post")
        axes[0].legend(loc="upper left", fontsize=7, ncol=3)
    axes[0].set_ylabel("triangles")
    axes[0].set_title(f"{result['scene']}: {Path(result['bag']['path']).name}")
    axes[1].plot(s["step_time"], s["step_ms"], lw=0.8, label="step")
    axes[1].plot(s["step_time"], s["solve_ms"], lw=0.8, label="linear solve")
    axes[1].plot(s["step_time"], s["lod_ms"], lw=0.8, label="LOD")
    axes[1].set_ylabel("ms per step")
    axes[1].legend(fontsize=8)
    axes[2].plot(s["rtf_time"], s["rtf"], lw=0.8)
    axes[2].axhline(1.0, color="grey", lw=0.5, ls="--")
    axes[2].set_ylabel("real-time factor")
    axes[2].set_xlabel("simulated time, s")
    fig.tight_layout()
    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=90)
    plt.close(fig)
    return png
