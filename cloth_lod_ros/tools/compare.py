"""``cloth-lod compare``: adaptive against uniform, and both against the converged motion.

Design §5.  Two runs of one scene with the same frame period: the *candidate*
(default: adaptive, maximum level L) and the *baseline* (default: uniform at
level L).  Both are sampled at a fixed (u, v) grid (barycentric interpolation
in the containing triangle) at a quarter, half and all of the run, and
compared with the **reference**:

* ``converged`` (default): the scene uniform at ``reference_level`` (default
  L) integrated by ``sdirk2`` at ``h_ref = H/8`` with 3 Newton iterations to
  1e-8 m (:mod:`cloth_lod_ros.tools.reference`), with its own error
  estimated by a second run at ``2 h_ref`` (time) and, with
  ``mesh_check``, a run one level coarser (mesh);
* ``same-step``: the baseline itself, as before: the distance between the two
  runs at the same step is mesh error only, and is labelled so.

In either mode the distance between candidate and baseline is reported too.
"""

from __future__ import annotations

import os
import time as _time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..sim.scene.config import load_scene
from ..sim.mesh.sampling import material_grid, rms_and_max_distance
from ..sim import ClothSim
from .reference import MODES, SAME_STEP_LABEL, ConvergedReference, self_error

__all__ = ["RunSummary", "compare_adaptive_uniform", "format_comparison"]


@dataclass
class RunSummary:
    """One run: cost, mesh size and sampled surfaces.

    Attributes:
        label: ``"uniform"``/``"baseline"``, ``"adaptive"``/``"candidate"`` or
            ``"reference"``.
        mean_step_ms, median_step_ms: wall time per step (one frame), ms.
        wall_per_sim_s: wall seconds per simulated second.
        lod_share: fraction of step time in LOD (criterion, operations, refresh).
        mean_triangles, max_triangles, final_triangles: active triangle counts.
        cg_iterations_mean: mean CG iterations per step.
        substeps_mean, rejected_steps, newton_iterations_mean, solves_mean:
            integrator steps per frame, rejected attempts (total), Newton
            iterations and linear solves per frame.
        splits, merges: totals.
        samples: ``{time: (m, 3) positions}`` at the compared times (not in JSON).
    """

    label: str
    mean_step_ms: float
    median_step_ms: float
    wall_per_sim_s: float
    lod_share: float
    mean_triangles: float
    max_triangles: int
    final_triangles: int
    cg_iterations_mean: float
    substeps_mean: float
    rejected_steps: int
    newton_iterations_mean: float
    solves_mean: float
    splits: int
    merges: int
    integrator: str = ""
    time_step: float = 0.0
    samples: dict = field(repr=False, default_factory=dict)


def _run(scene, points: np.ndarray, times: list[float], label: str) -> RunSummary:
    sim = ClothSim(scene)
    h = scene.simulation.time_step
    steps = int(round(scene.simulation.duration / h))
    wanted = {int(round(t / h)): t for t in times}
    samples = {}
    wall = 0.0
    for k in range(1, steps + 1):
        t0 = _time.perf_counter()
        sim.step()
        wall += _time.perf_counter() - t0
        if k in wanted:
            samples[wanted[k]] = sim.sample(points)
    st = sim.stats
    step_ms = np.array([s.step_ms for s in st])
    tris = np.array([s.triangle_count for s in st])
    return RunSummary(
        label=label, mean_step_ms=float(step_ms.mean()),
        median_step_ms=float(np.median(step_ms)), wall_per_sim_s=wall / (steps * h),
        lod_share=float(sum(s.lod_ms for s in st) / step_ms.sum()),
        mean_triangles=float(tris.mean()), max_triangles=int(tris.max()),
        final_triangles=int(tris[-1]),
        cg_iterations_mean=float(np.mean([s.cg_iterations for s in st])),
        substeps_mean=float(np.mean([s.substeps for s in st])),
        rejected_steps=int(sum(s.rejected_steps for s in st)),
        newton_iterations_mean=float(np.mean([s.newton_iterations for s in st])),
        solves_mean=float(np.mean([s.solves for s in st])),
        splits=int(sum(s.refines for s in st)), merges=int(sum(s.merges for s in st)),
        integrator=scene.simulation.integrator, time_step=h, samples=samples)


def _distances(run: RunSummary, reference: dict, times: list[float], side: float) -> list[dict]:
    out = []
    for t in times:
        rms, worst = rms_and_max_distance(run.samples[t], reference[t])
        out.append(dict(time=t, rms_m=rms, max_m=worst, rms_fraction=rms / side,
                        max_fraction=worst / side))
    return out


def compare_adaptive_uniform(scene_name: str, level: int | None = None,
                             duration: float | None = None,
                             overrides: list[str] | None = None,
                             times: list[float] | None = None,
                             grid: int = 21,
                             candidate: list[str] | None = None,
                             reference: list[str] | None = None,
                             baseline: list[str] | None = None,
                             mode: str = "converged",
                             reference_level: int | None = None,
                             reference_divisor: int = 8,
                             mesh_check: bool = False) -> dict:
    """Run a scene as candidate and baseline and measure both against the reference.

    Args:
        scene_name: built-in scene or YAML path.
        level: maximum/uniform level (default: the scene's).
        duration: simulated seconds (default: the scene's).
        overrides: extra ``key=value`` overrides for every run.
        times: sample times, s (default: quarter points and the end).
        grid: the (u, v) sample grid is ``grid × grid`` points over the cloth.
        candidate, baseline: overrides for one run only, applied after the
            defaults (``lod.enabled=true`` and ``lod.enabled=false``), e.g.
            ``candidate=["lod.enabled=false", "cloth.level=4"]``.
        reference: overrides for the reference: the converged runs (after their
            own settings), or with ``mode="same-step"`` the baseline run.
        mode: ``"converged"`` or ``"same-step"`` (module docstring).
        reference_level: level of the converged reference (default ``level``;
            never coarser than the runs compared).
        reference_divisor: ``h_ref = time_step / reference_divisor``.
        mesh_check: also run the converged reference one level coarser.

    Returns:
        A JSON-ready dict: ``uniform`` (the baseline) and ``adaptive`` (the
        candidate) summaries, ``speedup``, ``reference`` (what it is, its cost
        and its own estimated error per time), ``errors`` (candidate vs
        reference), ``uniform_errors`` (baseline vs reference) and
        ``same_step_errors`` (candidate vs baseline, mesh error only); every
        distance in m and as a fraction of the cloth's larger side.

    Raises:
        ValueError: a bad mode, level or divisor.
    """
    if mode not in MODES:
        raise ValueError(f"reference must be one of {', '.join(MODES)}, got {mode!r}")
    if grid < 2:
        raise ValueError(f"--grid must be at least 2, got {grid}")
    base = list(overrides or [])
    if level is not None:
        base.append(f"cloth.level={level}")
    if duration is not None:
        base.append(f"simulation.duration={duration}")
    candidate_over = base + ["lod.enabled=true"] + list(candidate or [])
    baseline_over = (base + ["lod.enabled=false"] + list(baseline or [])
                     + (list(reference or []) if mode == "same-step" else []))
    adaptive_scene = load_scene(scene_name, candidate_over)
    uniform_scene = load_scene(scene_name, baseline_over)
    sim_time = adaptive_scene.simulation.duration
    h = adaptive_scene.simulation.time_step
    if times is None:
        times = [sim_time / 4, sim_time / 2, sim_time]
    times = [round(t / h) * h for t in times if 0 < t <= sim_time + 1e-12]
    cloth = uniform_scene.cloth
    points = material_grid(cloth.width, cloth.height, grid)
    side = max(cloth.width, cloth.height)
    finest = max(adaptive_scene.cloth.level, uniform_scene.cloth.level)
    ref_cfg = None
    ref_scenes = []
    if mode == "converged":
        ref_level = finest if reference_level is None else reference_level
        if ref_level < finest:
            raise ValueError(f"reference level {ref_level} is coarser than the runs compared "
                             f"(level {finest}); the reference must be the finest")
        ref_cfg = ConvergedReference(ref_level, h, reference_divisor)
        for run in ref_cfg.runs(mesh_check):
            ref_scenes.append((run, load_scene(scene_name, base + run["overrides"]
                                               + list(reference or []))))
    uniform = _run(uniform_scene, points, times, "reference" if mode == "same-step"
                   and reference else "baseline" if baseline else "uniform")
    adaptive = _run(adaptive_scene, points, times, "candidate" if candidate else "adaptive")
    strip = lambda r: {k: v for k, v in asdict(r).items() if k != "samples"}  # noqa: E731
    same_step = _distances(adaptive, uniform.samples, times, side)
    result = dict(
        scene=adaptive_scene.name, level=cloth.level, time_step=h, duration=sim_time,
        candidate_overrides=list(candidate or []), baseline_overrides=list(baseline or []),
        reference_overrides=list(reference or []),
        sample_points=len(points), threads=os.environ.get("OMP_NUM_THREADS", "unset"),
        uniform=strip(uniform), adaptive=strip(adaptive),
        speedup=uniform.mean_step_ms / adaptive.mean_step_ms, same_step_errors=same_step)
    if mode == "same-step":
        result.update(reference=dict(mode=mode, label=SAME_STEP_LABEL, level=cloth.level,
                                     time_step=h),
                      errors=same_step, uniform_errors=None)
        return result
    refs = {}
    for run, scene in ref_scenes:
        refs[run["kind"]] = _run(scene, points, times, run["key"])
    ref = refs["reference"]
    own = []
    for t in times:
        est = self_error(ref.samples[t], refs["reference_2h"].samples[t],
                         refs["reference_coarse"].samples[t] if "reference_coarse" in refs
                         else None, side)
        own.append(dict(time=t, **est))
    result.update(
        reference=dict(ref_cfg.as_dict(), runs={k: strip(v) for k, v in refs.items()},
                       own_error=own),
        errors=_distances(adaptive, ref.samples, times, side),
        uniform_errors=_distances(uniform, ref.samples, times, side))
    return result


def _pct(x) -> str:
    return "—" if x is None else f"{100 * x:.3g} %"


def format_comparison(result: dict) -> str:
    """Human-readable table of :func:`compare_adaptive_uniform`'s result."""
    u, a, ref = result["uniform"], result["adaptive"], result["reference"]
    lines = [
        f"{result['scene']}: level {result['level']}, h = {result['time_step']:.4g} s, "
        f"{result['duration']:.3g} s simulated, {result['sample_points']} sample points",
        f"  reference: {ref['label']}",
        f"  {'':9s} {'ms/step':>8s} {'s/sim s':>8s} {'tris mean/max/final':>20s} "
        f"{'CG it':>6s} {'subst':>5s} {'solves':>6s} {'LOD %':>6s} {'splits':>7s} "
        f"{'merges':>7s}",
    ]
    rows = [u, a] + ([ref["runs"]["reference"]] if "runs" in ref else [])
    for r in rows:
        lines.append(
            f"  {r['label'][:9]:9s} {r['mean_step_ms']:8.2f} {r['wall_per_sim_s']:8.3g} "
            f"{r['mean_triangles']:8.0f}/{r['max_triangles']:5d}/{r['final_triangles']:5d} "
            f"{r['cg_iterations_mean']:6.1f} {r['substeps_mean']:5.2f} {r['solves_mean']:6.2f} "
            f"{100 * r['lod_share']:6.1f} {r['splits']:7d} {r['merges']:7d}")
    lines.append(f"  speed-up (mean step time): {result['speedup']:.2f}x")
    if ref["mode"] == "same-step":
        lines.append(f"  {a['label']} vs {u['label']}, {SAME_STEP_LABEL}:")
        for e in result["errors"]:
            lines.append(f"    t = {e['time']:5.2f} s: RMS {1e3 * e['rms_m']:.2f} mm "
                         f"({100 * e['rms_fraction']:.2f} % of side), max "
                         f"{1e3 * e['max_m']:.2f} mm")
        return "\n".join(lines)
    lines.append("  RMS distance from the converged reference, % of side (max in brackets);"
                 " the reference's own error: time = |ref(2h) - ref(h)|/3, mesh = distance "
                 "to one level coarser:")
    lines.append(f"    {'t s':>6s} {u['label'][:9]:>18s} {a['label'][:9]:>18s} "
                 f"{'ref time err':>13s} {'ref mesh err':>13s} {'same-step*':>11s}")
    for eu, ea, own, ss in zip(result["uniform_errors"], result["errors"],
                               result["reference"]["own_error"], result["same_step_errors"]):
        lines.append(
            f"    {ea['time']:6.3g} {_pct(eu['rms_fraction']):>8s} ({_pct(eu['max_fraction']):>7s})"
            f" {_pct(ea['rms_fraction']):>8s} ({_pct(ea['max_fraction']):>7s})"
            f" {_pct(own['time_rms']):>13s} {_pct(own['mesh_rms']):>13s}"
            f" {_pct(ss['rms_fraction']):>11s}")
    lines.append(f"    * {a['label']} vs {u['label']}: {SAME_STEP_LABEL}")
    if ref.get("own_error") and ref["own_error"][0]["mesh_rms"] is None:
        lines.append("    (mesh error of the reference not estimated: add --mesh-check)")
    return "\n".join(lines)
