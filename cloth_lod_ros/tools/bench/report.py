"""``cloth-lod bench`` summary: ``bench.md``, tables and paragraphs written from the numbers."""

from __future__ import annotations

from ..reference import SAME_STEP_LABEL
from .analysis import (comparison_table, families, other, pareto, pct, rest_shape_section,
                       same_computations, table, time_tag, uniform_rows, verdict_sentences,
                       why_table)

__all__ = ["PAPER", "markdown"]

#: The paper's §6 numbers (2003 hardware): mean CPU ms per frame over the first
#: 2 s, adaptive (max level 6, 25-particle start) against uniform 33 × 33.
PAPER = dict(adaptive_ms=284.5, uniform_ms=3012.7, ratio=3012.7 / 284.5, lod_share=0.03)


def _cost_text(r: dict) -> str:
    return (f"{r['wall_per_sim_s_median']:.3g} ({r['wall_per_sim_s_min']:.3g}–"
            f"{r['wall_per_sim_s_max']:.3g})")


def _tag_header(tag: str) -> str:
    return "at rest" if tag == "rest" else tag.replace("s", " s")


def own_error_line(result: dict) -> str:
    """One sentence with the reference's own error during motion and at rest,
    for under every table."""
    ref = result["reference"]
    if ref["mode"] != "converged":
        return f"Errors are against a {SAME_STEP_LABEL}."
    own = ref["own_error"]
    mesh = (f"mesh error (distance to L{ref['level'] - 1}) {pct(own['motion']['mesh_rms'])} "
            f"during motion, {pct(own['rest']['mesh_rms'])} at rest"
            if own["motion"]["mesh_rms"] is not None else "mesh error not estimated "
            "(`--no-mesh-check`)")
    return (f"The converged reference's own error, RMS: time error (|ref(2 h_ref) − "
            f"ref(h_ref)|/3) {pct(own['motion']['time_rms'])} during motion; {mesh}.")


def _header(result: dict) -> list[str]:
    s, m = result["settings"], result["machine"]
    return [f"# cloth-lod bench: {s['scene']}", "",
            f"Command: `{s['command']}` (or `python -m cloth_lod_ros.tools.bench` with the "
            "same arguments)  ",
            f"Machine: {m['cpu_model']}, {m['logical_cpus']} logical CPUs (each run pinned to "
            f"CPU {m['pinned_cpu']}, one thread), {m['platform']}; Python {m['python']}, "
            f"numpy {m['numpy']}, scipy {m['scipy']}; commit {m['git_commit'] or '?'}; "
            f"{m['date']}.  ",
            f"Wall time of the whole benchmark: {result['wall_s'] / 60:.1f} min; 1-minute load "
            f"average during the runs {result['load_min']:.2f}–{result['load_max']:.2f} "
            "(the machine is shared; a load above 1 on 2 CPUs means other work competed for "
            "the cores, so compare the min–max ranges, not only the medians).", ""]


def _setup(result: dict) -> list[str]:
    s, rows, rest, ref = (result["settings"], result["rows"], result["rest"],
                          result["reference"])
    times = s["times"]
    md = ["## Set-up", "",
          f"- Scene `{s['scene']}`, {s['duration']:g} s simulated; frame period h = "
          f"{s['time_step']:.6g} s (`simulation.time_step`, the largest step; every run is "
          f"sampled once per frame); cloth side {s['side_m']:g} m (1 % of the side = "
          f"{10 * s['side_m']:g} mm).",
          "- Families (`--schemes`): " + "; ".join(
              f"`{f['spec']}` = {f['label']}" for f in s["families"])
          + f". Scene default: `simulation.integrator: {s['scene_default']['integrator']}`, "
          f"`error_tolerance: {s['scene_default']['error_tolerance']:g}`. Each family runs "
          f"uniform at levels {', '.join(map(str, s['levels']))} and adaptive at maximum "
          f"level {', '.join(map(str, s['max_levels']))} with refine threshold "
          f"{', '.join(f'{t * 1e3:g}' for t in s['thresholds'])} mm (coarsen = "
          f"{s['coarsen_ratio']:g} × refine, the scene's ratio), starting from level "
          f"{s['initial_level']}."]
    if ref["mode"] == "converged":
        runs = ref["runs"]
        main = runs["reference"]
        md.append(
            f"- **Reference: the converged motion**, approximated by the scene uniform at "
            f"level {ref['level']}, `sdirk2` (second order) with a fixed step h_ref = "
            f"h/{ref['divisor']:g} = {ref['time_step']:.4g} s, {ref['newton_iterations']} Newton "
            f"iterations per stage to {ref['newton_tolerance']:g} m, no error control "
            f"({main['solves_per_step']:.1f} solves per step, {main['wall_per_sim_s']:.3g} s "
            "per simulated second, run once). Its own error is estimated by a run at 2 h_ref "
            "(time: |ref(2 h_ref) − ref(h_ref)|/3 for a second-order method)"
            + (f" and a run one level coarser, L{ref['level'] - 1} (mesh: the distance "
               "between the two is the size of the reference's mesh error)"
               if "reference_coarse" in runs else "")
            + ". After the timed window it goes on to rest at the frame period h (a resting "
            "shape is an equilibrium of the model on its mesh, which the step does not "
            "change; at rest only the mesh estimate applies).")
    else:
        md.append(f"- **Reference: {SAME_STEP_LABEL}.** Each family is compared with its own "
                  f"uniform level-{ref['level']} run at the same h and integrator settings, "
                  "so every error below leaves out the time integration's error.")
    md += [f"- Error: RMS and max 3-D distance from the reference over a {s['grid']} × "
           f"{s['grid']} grid of material points, as a fraction of the side, at t = "
           + ", ".join(f"{t:.4g}" for t in times) + " s and at rest. \"During motion\" is the "
           "RMS over those times.",
           f"- At rest: the first time after {s['duration']:g} s at which the reference's "
           f"kinetic energy per unit mass stayed below {s['rest_threshold']:g} J/kg for "
           f"{s['rest_window']:g} s, capped at {s['rest_cap']:g} s: "
           + (f"t = {rest['time']:g} s." if rest["at_rest"] else
              f"**not reached by the cap**; sampled at t = {rest['time']:g} s "
              f"(reference kinetic energy {rest['ke_per_mass']:.2g} J/kg).")
           + " Every run is sampled at that time (its own kinetic energy there is "
           "`ke_per_mass_at_rest` in the CSV).",
           f"- Cost over the first {s['duration']:g} s only: wall (and CPU) seconds per "
           f"simulated second, median and min–max of {s['repeats']} runs, each a fresh "
           "process pinned to one CPU with every thread pool at 1, in rounds; per frame: "
           "integrator steps (substeps), Newton iterations (linearisations), linear solves "
           "and CG iterations; rejected steps in total; LOD share of the wall time.",
           "- The bench's clock around `ClothSim.step()` read at most "
           f"{pct(max(r['timing_overhead_share_max'] for r in rows))} more than the step's "
           "own clock (`StepStats.step_ms`)."]
    if any(r["repeat_max_deviation_m"] > 0 for r in rows):
        md.append("- **Repeats differ** (see `repeat_max_deviation_m`): runs are not "
                  "deterministic.")
    else:
        md.append("- Every repeat reproduced the first one's samples bit for bit.")
    return md + [""]


def _own_error_section(result: dict) -> list[str]:
    ref, s = result["reference"], result["settings"]
    if ref["mode"] != "converged":
        return []
    own = ref["own_error"]
    tags = [time_tag(t) for t in s["times"]] + ["rest"]
    cell = lambda e, what: (f"{pct(e[f'{what}_rms'])} ({pct(e[f'{what}_max'])})"  # noqa: E731
                            if e[f"{what}_rms"] is not None else "—")
    body = [["time: \\|ref(2 h_ref) − ref(h_ref)\\|/3"] + [cell(own[t], "time") for t in tags]
            + [cell(own["motion"], "time")]]
    if own["motion"]["mesh_rms"] is not None:
        body.append([f"mesh: \\|L{ref['level'] - 1} − L{ref['level']}\\| at h_ref"]
                    + [cell(own[t], "mesh") for t in tags] + [cell(own["motion"], "mesh")])
    md = ["## The reference's own error", "",
          "RMS (max) over the sample points, as a fraction of the side:", ""]
    md += table(["estimate"] + [_tag_header(t) for t in tags] + ["during motion"], body)
    time_est = own["motion"]["time_rms"] or 0.0
    floor = time_est + (own["motion"]["mesh_rms"] or 0.0)
    # Uniform runs on the reference's own mesh share its mesh error: for them
    # only the time estimate is a floor.
    same_mesh = lambda r: r["kind"] == "uniform" and r["level"] == ref["level"]  # noqa: E731
    for group, bound, what in (
            ([r for r in result["rows"] if not same_mesh(r)], floor,
             "the sum of both estimates"),
            ([r for r in result["rows"] if same_mesh(r)], time_est,
             f"the time estimate (uniform L{ref['level']} shares the reference's mesh, so its "
             "error is the time integration's alone)")):
        if group and bound > 0:
            best = min(group, key=lambda r: r["rms_frac_motion"])
            md += ["", f"Smallest error during motion: {pct(best['rms_frac_motion'])} "
                   f"({best['label']}), {best['rms_frac_motion'] / bound:.3g}× {what}."]
    return md + [""]


def _results(result: dict) -> list[str]:
    s, rows = result["settings"], result["rows"]
    tags = [time_tag(t) for t in s["times"]] + ["rest"]
    header = (["run", "wall s / sim s", "CPU s / sim s", "ms / frame", "substeps / frame (max)",
               "rejected", "Newton it. / frame", "solves / frame", "CG it. / frame",
               "triangles mean", "LOD share"]
              + [f"RMS {_tag_header(t)}" for t in tags] + ["RMS motion", "max motion"])
    body = []
    for r in rows:
        body.append([r["label"], _cost_text(r), f"{r['cpu_per_sim_s_median']:.3g}",
                     f"{r['ms_per_frame_median']:.3g}",
                     f"{r['substeps_per_frame']:.2f} ({r['substeps_max']})",
                     f"{r['rejected_steps']}", f"{r['newton_iterations_per_frame']:.2f}",
                     f"{r['solves_per_frame']:.2f}", f"{r['cg_iterations_per_frame']:.0f}",
                     f"{r['triangles_mean']:.0f}",
                     pct(r["lod_share_median"]) if r["kind"] == "adaptive" else "—"]
                    + [pct(r[f"rms_frac_{t}"]) + (" †" if t == "rest" and other(r) else "")
                       for t in tags]
                    + [pct(r["rms_frac_motion"]), pct(r["max_frac_motion"])])
    md = ["## Results", ""] + table(header, body)
    md += ["", own_error_line(result)]
    if result["reference"]["mode"] == "converged":
        md[-1] += (f" Uniform L{result['reference']['level']} runs share the reference's mesh: "
                   "their error is the time integration's alone.")
    if any(other(r) for r in rows):
        md += ["", "† settled into another shape than the reference: its largest distance at "
               "rest is more than twice its largest distance during motion, or it is a uniform "
               "run on the reference's mesh and at rest it is farther from the reference than "
               "the reference's own mesh error; see \"At rest: which shape\" below."]
    same = same_computations(rows)
    if same:
        md += ["", "Same computation, different labels: " + "; ".join(
            f"{b['label']} never refined past what {a['label']} did, so the gap between "
            f"their costs, {a['wall_per_sim_s_median']:.3g} and "
            f"{b['wall_per_sim_s_median']:.3g} s per simulated second, is timing noise"
            for a, b in same) + "."]
    return md + ["", "![error against cost](bench.png)", ""]


def _headline(result: dict) -> list[str]:
    """Per family: the finest uniform level and each adaptive run, error and
    cost relative to the first family's same mesh (ratios from one run)."""
    rows = result["rows"]
    fams = families(rows)
    if not fams:
        return []
    first = {(r["kind"] in ("uniform", "same_step"), r["level"], r["refine_threshold_m"]): r
             for r in fams[0][1]}
    body = []
    for _, fam_rows in fams:
        uni = uniform_rows(fam_rows)
        picks = ([max(uni, key=lambda r: r["level"])] if uni else []) + [
            r for r in fam_rows if r["kind"] == "adaptive"]
        for r in picks:
            base = first.get((r["kind"] in ("uniform", "same_step"), r["level"],
                              r["refine_threshold_m"]))
            ratio = (f"{r['wall_per_sim_s_median'] / base['wall_per_sim_s_median']:.2f}×"
                     if base else "—")
            body.append([r["label"], pct(r["rms_frac_motion"]), pct(r["rms_frac_rest"])
                         + (" †" if other(r) else ""), _cost_text(r), ratio,
                         f"{r['substeps_per_frame']:.2f}", f"{r['solves_per_frame']:.2f}"])
    md = ["## Speed against error", "",
          f"Each family on the finest uniform mesh and on the adaptive mesh; cost ratios "
          f"to the first family ({fams[0][1][0]['label'].rsplit(', ', 1)[0]}) on the same "
          "mesh, from the same run:", ""]
    md += table(["run", "RMS during motion", "RMS at rest", "wall s / sim s",
                 "cost × first family", "substeps / frame", "solves / frame"], body)
    front = pareto(rows, "rms_frac_motion")
    md += ["", "**Cheapest for its accuracy during motion** (no other run is both cheaper "
           "and more accurate): " + "; ".join(
               f"{r['label']} ({pct(r['rms_frac_motion'])}, {r['wall_per_sim_s_median']:.3g} "
               "s/s)" for r in front) + ".", "", own_error_line(result), ""]
    return md


def _paper(result: dict) -> list[str]:
    s, paper = result["settings"], result.get("paper")
    md = ["## The paper's comparison on our code", ""]
    if not paper:
        return md + ["Not available: the run needs the `baraff_witkin` family with a fixed "
                     "step, the scene's level among `--levels` and `--max-levels` and its "
                     "refine threshold among `--thresholds`.", ""]
    md += [f"Mean time per frame over the first {s['duration']:g} s, in the paper's own "
           f"configuration (`baraff_witkin`, one step per frame): adaptive (max level "
           f"{paper['level']}, threshold {paper['threshold'] * 1e3:g} mm, as in the scene) "
           f"against uniform level {paper['level']} ({paper['grid']} × {paper['grid']} "
           "particles), median (min–max) of the repeats; the ratio is computed per round.", ""]
    md += table(
        ["", "adaptive ms / frame", "uniform ms / frame", "ratio", "LOD share",
         "adaptive RMS motion / rest", "uniform RMS motion / rest"],
        [["paper (2003 hardware)", f"{PAPER['adaptive_ms']:.1f}", f"{PAPER['uniform_ms']:.1f}",
          f"{PAPER['ratio']:.1f}×", "~3 %", "not given", "not given"],
         ["this code", paper["adaptive_ms_text"], paper["uniform_ms_text"], paper["ratio_text"],
          f"{pct(paper['lod_share'])} (≤ {pct(paper['lod_share_upper'])})",
          f"{pct(paper['adaptive_rms_motion'])} / {pct(paper['adaptive_rms_rest'])}",
          f"{pct(paper['uniform_rms_motion'])} / {pct(paper['uniform_rms_rest'])}"]])
    return md + ["", "LOD share: as `StepStats.lod_ms` books it; in brackets, plus the adaptive "
                 "run's unattributed share beyond the uniform run's. " + own_error_line(result),
                 ""]


def markdown(result: dict) -> str:
    rows = result["rows"]
    md = _header(result) + _setup(result) + _own_error_section(result) + _results(result)
    md += _headline(result) + _paper(result)
    if any(r["kind"] == "adaptive" for r in rows):
        md += ["## Does adaptive beat uniform?", "",
               "Within each family (same integrator settings), so that the comparison is "
               "about the mesh. Verdicts use measured points only; \"dominates\" means "
               "cheaper (median wall time) *and* more accurate. The uniform curve column "
               "interpolates between the family's measured uniform levels in log–log.", ""]
        for key, what in (("rms_frac_motion", "During motion"), ("rms_frac_rest", "At rest")):
            md += [verdict_sentences(rows, key, what), ""] + comparison_table(rows, key) + [""]
        md += [own_error_line(result), ""]
    md += rest_shape_section(rows)
    why = why_table(rows)
    if why:
        md += ["Where the time goes: the triangles each adaptive run simulates and what a "
               "triangle-frame costs (wall time per frame / mean triangles), against the "
               "uniform level of nearest cost in its family. \"Unattributed\" is step time "
               "that `StepStats` books to none of LOD, forces, assembly and solve.", ""]
        md += why + [""]
    md += ["Files: `bench.csv` (one row per configuration), `bench.json` (the same rows plus "
           "machine, settings, the reference's runs and own error, and every repeat), "
           "`bench.png`.", ""]
    return "\n".join(md)
