"""Adaptive against uniform: time per step and distance at shared material points.

Design §5: the reference is the same scene on the uniform mesh at the
adaptive run's maximum level, with the same time step.  Both cloths are sampled
at a fixed (u, v) grid (barycentric interpolation in the containing triangle)
and compared by RMS and maximum 3-D distance.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field

import numpy as np

from ..sim.config import load_scene
from ..sim.metrics import material_grid, rms_and_max_distance
from ..sim import ClothSim

__all__ = ["RunSummary", "compare_adaptive_uniform"]


@dataclass
class RunSummary:
    """One run: cost, mesh size and sampled surfaces.

    Attributes:
        label: ``"uniform"`` or ``"adaptive"``.
        mean_step_ms, median_step_ms: wall time per step, ms.
        lod_share: fraction of step time in LOD (criterion, operations, refresh).
        mean_triangles, max_triangles, final_triangles: active triangle counts.
        cg_iterations_mean: mean CG iterations per step.
        splits, merges: totals.
        samples: ``{time: (m, 3) positions}`` at the compared times (not in JSON).
    """

    label: str
    mean_step_ms: float
    median_step_ms: float
    lod_share: float
    mean_triangles: float
    max_triangles: int
    final_triangles: int
    cg_iterations_mean: float
    splits: int
    merges: int
    samples: dict = field(repr=False, default_factory=dict)


def _run(scene, points: np.ndarray, times: list[float], label: str) -> RunSummary:
    sim = ClothSim(scene)
    steps = int(round(scene.simulation.duration / scene.simulation.time_step))
    wanted = {int(round(t / scene.simulation.time_step)): t for t in times}
    samples = {}
    for k in range(1, steps + 1):
        sim.step()
        if k in wanted:
            samples[wanted[k]] = sim.sample(points)
    st = sim.stats
    step_ms = np.array([s.step_ms for s in st])
    tris = np.array([s.triangle_count for s in st])
    return RunSummary(
        label=label, mean_step_ms=float(step_ms.mean()),
        median_step_ms=float(np.median(step_ms)),
        lod_share=float(sum(s.lod_ms for s in st) / step_ms.sum()),
        mean_triangles=float(tris.mean()), max_triangles=int(tris.max()),
        final_triangles=int(tris[-1]),
        cg_iterations_mean=float(np.mean([s.cg_iterations for s in st])),
        splits=int(sum(s.refines for s in st)), merges=int(sum(s.merges for s in st)),
        samples=samples)


def compare_adaptive_uniform(scene_name: str, level: int | None = None,
                             duration: float | None = None,
                             overrides: list[str] | None = None,
                             times: list[float] | None = None,
                             grid: int = 21,
                             candidate: list[str] | None = None,
                             reference: list[str] | None = None) -> dict:
    """Run a scene twice and compare: by default adaptive (max level ``level``)
    against uniform at that level.

    Args:
        scene_name: built-in scene or YAML path.
        level: maximum/uniform level (default: the scene's).
        duration: simulated seconds (default: the scene's).
        overrides: extra ``key=value`` overrides for both runs.
        times: sample times, s (default: quarter points and the end).
        grid: the (u, v) sample grid is ``grid × grid`` points over the cloth.
        candidate, reference: overrides for one run only, applied after the
            defaults (``lod.enabled=true`` and ``lod.enabled=false``), e.g.
            ``candidate=["lod.enabled=false", "cloth.level=4"]`` compares a
            coarser uniform mesh with the reference.

    Returns:
        A JSON-ready dict: both runs' summaries, the speed-up, and per time the
        RMS and max distance in m and as a fraction of the cloth's larger side.
    """
    base = list(overrides or [])
    if level is not None:
        base.append(f"cloth.level={level}")
    if duration is not None:
        base.append(f"simulation.duration={duration}")
    adaptive_scene = load_scene(scene_name, base + ["lod.enabled=true"] + list(candidate or []))
    uniform_scene = load_scene(scene_name, base + ["lod.enabled=false"] + list(reference or []))
    sim_time = adaptive_scene.simulation.duration
    h = adaptive_scene.simulation.time_step
    if times is None:
        times = [sim_time / 4, sim_time / 2, sim_time]
    times = [round(t / h) * h for t in times if 0 < t <= sim_time + 1e-12]
    cloth = uniform_scene.cloth
    points = material_grid(cloth.width, cloth.height, grid)
    uniform = _run(uniform_scene, points, times, "reference" if reference else "uniform")
    adaptive = _run(adaptive_scene, points, times, "candidate" if candidate else "adaptive")
    side = max(cloth.width, cloth.height)
    errors = []
    for t in times:
        rms, worst = rms_and_max_distance(adaptive.samples[t], uniform.samples[t])
        errors.append(dict(time=t, rms_m=rms, max_m=worst, rms_fraction=rms / side,
                           max_fraction=worst / side))
    strip = lambda r: {k: v for k, v in asdict(r).items() if k != "samples"}  # noqa: E731
    return dict(
        scene=adaptive_scene.name, level=cloth.level, time_step=h, duration=sim_time,
        candidate_overrides=list(candidate or []), reference_overrides=list(reference or []),
        sample_points=len(points), threads=os.environ.get("OMP_NUM_THREADS", "unset"),
        uniform=strip(uniform), adaptive=strip(adaptive),
        speedup=uniform.mean_step_ms / adaptive.mean_step_ms, errors=errors)


def format_comparison(result: dict) -> str:
    """Human-readable table of :func:`compare_adaptive_uniform`'s result."""
    u, a = result["uniform"], result["adaptive"]
    lines = [
        f"{result['scene']}: level {result['level']}, h = {result['time_step']:.4g} s, "
        f"{result['duration']:.3g} s simulated, {result['sample_points']} sample points",
        f"  {'':9s} {'ms/step':>8s} {'median':>8s} {'tris mean/max/final':>20s} "
        f"{'CG it':>6s} {'LOD %':>6s} {'splits':>7s} {'merges':>7s}",
    ]
    for r in (u, a):
        lines.append(
            f"  {r['label']:9s} {r['mean_step_ms']:8.2f} {r['median_step_ms']:8.2f} "
            f"{r['mean_triangles']:8.0f}/{r['max_triangles']:5d}/{r['final_triangles']:5d} "
            f"{r['cg_iterations_mean']:6.1f} {100 * r['lod_share']:6.1f} "
            f"{r['splits']:7d} {r['merges']:7d}")
    lines.append(f"  speed-up (mean step time): {result['speedup']:.2f}x")
    for e in result["errors"]:
        lines.append(f"  t = {e['time']:5.2f} s: {a['label']} vs {u['label']} RMS {1e3 * e['rms_m']:.2f} mm "
                     f"({100 * e['rms_fraction']:.2f} % of side), max {1e3 * e['max_m']:.2f} mm")
    return "\n".join(lines)
