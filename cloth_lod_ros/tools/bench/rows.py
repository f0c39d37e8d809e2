"""``cloth-lod bench``: table rows from the runs - cost over the repeats, error
against the reference, and the reference's own error."""

from __future__ import annotations

import math

import numpy as np

from ..reference import self_error
from .analysis import time_tag

__all__ = ["config_row", "reference_summary", "paper_row", "flag_other_shapes"]


def _rms_motion(values: list) -> float | None:
    """One number for "during motion": RMS over the sample times of RMS values."""
    if not values or any(v is None for v in values):
        return None
    return float(np.sqrt(np.mean(np.square(values))))


def config_row(cfg: dict, runs: list[dict], reference: np.ndarray, times: list[float],
               side: float, points: np.ndarray, family: dict | None,
               reference_label: str = "converged") -> dict:
    """One table row: cost over the repeats and error of the first repeat.

    ``reference``: (k, m, 3) reference samples at ``times`` and at rest (m);
    ``points``: (m, 2) their material coordinates (m); ``reference_label``:
    what the errors are measured against (the ``reference`` column).
    """
    first = runs[0]
    sampled = np.asarray(first["samples"], dtype=float)
    sim_s = first["cost"]["simulated_s"]
    walls = np.array([r["cost"]["wall_s"] for r in runs]) / sim_s
    cpus = np.array([r["cost"]["cpu_s"] for r in runs]) / sim_s
    lod = np.array([r["cost"]["lod_ms"] / (1e3 * r["cost"]["wall_s"]) for r in runs])
    # Self-collision (detection and checks; its re-solves are in solve_ms), of the step.
    own = np.array([r["cost"].get("self_collision_ms", 0.0) / r["cost"]["internal_step_ms"]
                    for r in runs])
    # Step time that StepStats gives to none of LOD, forces, assembly, solve
    # (energies, statistics, the step-size control's own tests).
    other = np.array([1.0 - (r["cost"]["lod_ms"] + r["cost"]["force_ms"] + r["cost"]["assembly_ms"]
                             + r["cost"]["solve_ms"]) / r["cost"]["internal_step_ms"]
                      for r in runs])
    # The bench's clock around sim.step() against the step's own clock.
    overhead = np.array([1.0 - r["cost"]["internal_step_ms"] / (1e3 * r["cost"]["wall_s"])
                         for r in runs])
    c = first["cost"]
    frames = c["steps"]
    row = dict(
        config=cfg["key"], label=cfg["label"], reference=reference_label, kind=cfg["kind"],
        family=cfg["family"],
        integrator=family["integrator"] if family else "",
        error_tolerance_m=family["tolerance"] if family else 0.0,
        level=cfg["level"], refine_threshold_m=cfg["threshold"],
        coarsen_threshold_m=cfg["coarsen"], time_step_s=cfg["time_step"], repeats=len(runs),
        wall_per_sim_s_median=float(np.median(walls)), wall_per_sim_s_min=float(walls.min()),
        wall_per_sim_s_max=float(walls.max()),
        cpu_per_sim_s_median=float(np.median(cpus)),
        ms_per_frame_median=float(np.median(walls) * cfg["time_step"] * 1e3),
        substeps_per_frame=c["substeps"] / frames, substeps_max=c["substeps_max"],
        rejected_steps=c["rejected_steps"], smallest_step_s=c["smallest_step"],
        newton_iterations_per_frame=c["newton_iterations"] / frames,
        solves_per_frame=c["solves"] / frames,
        lod_share_median=float(np.median(lod)),
        self_collision_share_median=float(np.median(own)),
        unattributed_share_median=float(np.median(other)),
        timing_overhead_share_max=float(overhead.max()),
        vertex_steps=c["vertex_steps"], triangle_steps=c["triangle_steps"],
        cg_iterations=c["cg_iterations"],
        cg_iterations_per_frame=c["cg_iterations"] / frames,
        solver="+".join(c.get("solvers", [])),
        unconverged_steps=c["unconverged_steps"],
        triangles_mean=c["triangles_mean"], triangles_max=c["triangles_max"],
        triangles_final=c["triangles_final"], splits=c["splits"], merges=c["merges"])
    # Same inputs, same single thread: every repeat must give the same cloth.
    deviation = 0.0
    for r in runs[1:]:
        again = np.asarray(r["samples"], dtype=float)
        n = min(len(again), len(sampled))
        deviation = max(deviation, float(np.abs(again[:n] - sampled[:n]).max()))
    row["repeat_max_deviation_m"] = deviation
    tags = [time_tag(t) for t in times] + ["rest"]
    rms_all, worst_all = [], []
    for i, tag in enumerate(tags):
        dist = np.linalg.norm(sampled[i] - reference[i], axis=1)
        rms, worst = float(np.sqrt(np.mean(dist**2))), float(dist.max())
        row[f"rms_frac_{tag}"] = rms / side
        row[f"max_frac_{tag}"] = worst / side
        if tag != "rest":
            rms_all.append(rms)
            worst_all.append(worst)
    row["rms_frac_motion"] = _rms_motion(rms_all) / side
    row["max_frac_motion"] = max(worst_all) / side
    row["ke_per_mass_at_rest"] = first["ke_per_mass"][-1]
    # Where the cloth at rest is farthest from the reference, and which way.
    offset = sampled[-1] - reference[-1]
    worst = int(np.argmax(np.linalg.norm(offset, axis=1)))
    row["rest_worst_u_m"], row["rest_worst_v_m"] = (float(x) for x in points[worst])
    row["rest_worst_dx_m"], row["rest_worst_dy_m"], row["rest_worst_dz_m"] = (
        float(x) for x in offset[worst])
    # A run whose largest distance at rest is over twice its largest distance
    # while moving has settled into another shape (e.g. a fold that buckled
    # the other way), which is not "less accurate" in the usual sense.
    row["rest_other_shape"] = bool(row["max_frac_rest"] > 2.0 * row["max_frac_motion"])
    return row


def reference_summary(configs: list[dict], runs: dict, times: list[float],
                      side: float) -> dict:
    """The converged reference's runs (cost, once each) and its own error per
    sample time and at rest (:func:`~cloth_lod_ros.tools.reference.self_error`)."""
    by_kind = {c["kind"]: c for c in configs if c["kind"].startswith("reference")}
    samples = {k: np.asarray(runs[c["key"]][0]["samples"], dtype=float)
               for k, c in by_kind.items()}
    out_runs = {}
    for kind, cfg in by_kind.items():
        r = runs[cfg["key"]][0]
        c = r["cost"]
        out_runs[kind] = dict(
            key=cfg["key"], label=cfg["label"], level=cfg["level"],
            time_step_s=cfg["time_step"],
            wall_per_sim_s=c["wall_s"] / c["simulated_s"],
            cpu_per_sim_s=c["cpu_s"] / c["simulated_s"],
            solves_per_step=c["solves"] / c["steps"],
            newton_iterations_per_step=c["newton_iterations"] / c["steps"],
            cg_iterations_per_step=c["cg_iterations"] / c["steps"],
            unconverged_steps=c["unconverged_steps"], solver="+".join(c.get("solvers", [])),
            process_s=r.get("process_s"))
    ref, half, coarse = (samples.get(k) for k in ("reference", "reference_2h",
                                                  "reference_coarse"))
    own = {}
    for i, t in enumerate(times):
        own[time_tag(t)] = self_error(ref[i], None if half is None else half[i],
                                      None if coarse is None else coarse[i], side)
    own["rest"] = self_error(ref[-1], None,
                             coarse[-1] if coarse is not None and len(coarse) > len(times)
                             else None, side)
    motion = {}
    for what in ("time", "mesh"):
        motion[f"{what}_rms"] = _rms_motion([own[time_tag(t)][f"{what}_rms"] for t in times])
        maxima = [own[time_tag(t)][f"{what}_max"] for t in times]
        motion[f"{what}_max"] = None if None in maxima else max(maxima)
    own["motion"] = motion
    return dict(runs=out_runs, own_error=own)


def paper_row(rows: list[dict], runs: dict, scene) -> dict | None:
    """The paper's comparison in its own configuration (``baraff_witkin``, one
    step per frame): adaptive (scene's level and threshold) against uniform at
    that level, ms per frame per round, and both errors."""
    level, thr = scene.cloth.level, scene.lod.refine_threshold
    bw = [r for r in rows if r["integrator"] == "baraff_witkin" and r["error_tolerance_m"] == 0]
    uni = next((r for r in bw if r["kind"] in ("uniform", "same_step") and r["level"] == level),
               None)
    ada = next((r for r in bw if r["kind"] == "adaptive" and r["level"] == level
                and math.isclose(r["refine_threshold_m"], thr)), None)
    if uni is None or ada is None:
        return None
    ms = lambda key: np.array([1e3 * r["cost"]["wall_s"] / r["cost"]["steps"]  # noqa: E731
                               for r in runs[key]])
    a_ms, u_ms = ms(ada["config"]), ms(uni["config"])
    n = min(len(a_ms), len(u_ms))
    ratios = u_ms[:n] / a_ms[:n]
    text = lambda x: f"{np.median(x):.1f} ({x.min():.1f}–{x.max():.1f})"  # noqa: E731
    blocks_u, blocks_v = scene.cloth.base_blocks
    grid = (blocks_u * 2 ** (level // 2) + 1) if level % 2 == 0 else None
    return dict(level=level, threshold=thr, grid=grid if grid else "—",
                adaptive_ms=float(np.median(a_ms)), uniform_ms=float(np.median(u_ms)),
                ratio=float(np.median(ratios)), adaptive_ms_text=text(a_ms),
                uniform_ms_text=text(u_ms),
                ratio_text=f"{np.median(ratios):.2f}× ({ratios.min():.2f}–{ratios.max():.2f})",
                lod_share=ada["lod_share_median"],
                lod_share_upper=ada["lod_share_median"] + max(
                    ada["unattributed_share_median"] - uni["unattributed_share_median"], 0.0),
                adaptive_rms_motion=ada["rms_frac_motion"], adaptive_rms_rest=ada["rms_frac_rest"],
                uniform_rms_motion=uni["rms_frac_motion"], uniform_rms_rest=uni["rms_frac_rest"],
                adaptive_config=ada["config"], uniform_config=uni["config"])


def flag_other_shapes(result: dict) -> None:
    """Mark ``rest_other_shape`` on the rows of ``result`` (in place).

    Two signs that a run came to rest in another equilibrium than the
    reference (the hanging cloth has two): its largest distance at rest is
    over twice its largest during motion; or, against a converged reference,
    it is a uniform run on the reference's own mesh - no mesh error, and at
    rest the integrator does not change the equilibrium - and its RMS distance
    at rest exceeds the reference's own mesh error estimate there.
    """
    ref = result["reference"]
    mesh = (ref.get("own_error") or {}).get("rest", {}).get("mesh_rms")
    for row in result["rows"]:
        other = row["max_frac_rest"] > 2.0 * row["max_frac_motion"]
        if (ref["mode"] == "converged" and mesh and row["kind"] == "uniform"
                and row["level"] == ref["level"]):
            other = other or row["rms_frac_rest"] > mesh
        row["rest_other_shape"] = bool(other)
