"""``cloth-lod bench`` output: CSV, plot and the Markdown summary written from the numbers."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

#: The paper's §6 numbers (2003 hardware): mean CPU ms per frame over the first
#: 2 s, adaptive (max level 6, 25-particle start) against uniform 33 × 33.
PAPER = dict(adaptive_ms=284.5, uniform_ms=3012.7, ratio=3012.7 / 284.5, lod_share=0.03)


def _time_tag(t: float) -> str:
    return f"{t:.4g}s"


def _write_csv(path: Path, rows: list[dict]) -> None:
    fields = list(rows[0])
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            # repr() of a float reads back to the same float.
            writer.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v)
                             for k, v in row.items()})


def _plot(path: Path, rows: list[dict], summary: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("rms_frac_motion", "during motion: RMS over t = "
               + ", ".join(f"{t:.3g}" for t in summary["times"]) + " s"),
              ("rms_frac_rest", f"at rest (t = {summary['rest_time']:.3g} s); "
               "hollow: settled into another shape (†)")]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.2), sharey=False)
    ref = next(r for r in rows if r["kind"] == "reference")
    half = next((r for r in rows if r["kind"] == "half_step"), None)
    markers = {6: "s", 8: "^"}
    for ax, (key, title) in zip(axes, panels):
        groups = [("uniform", [r for r in rows if r["kind"] == "uniform"], "k", "o")]
        for level in sorted({r["level"] for r in rows if r["kind"] == "adaptive"}):
            groups.append((f"adaptive, max level {level}",
                           [r for r in rows if r["kind"] == "adaptive" and r["level"] == level],
                           "C0" if level <= 6 else "C3", markers.get(level, "D")))
        for name, group, colour, marker in groups:
            group = sorted((r for r in group if r[key] > 0),
                           key=lambda r: r["wall_per_sim_s_median"])
            if not group:
                continue
            x = np.array([r["wall_per_sim_s_median"] for r in group])
            y = np.array([r[key] for r in group])
            err = np.array([[r["wall_per_sim_s_median"] - r["wall_per_sim_s_min"]
                             for r in group],
                            [r["wall_per_sim_s_max"] - r["wall_per_sim_s_median"]
                             for r in group]])
            hollow = np.array([key == "rms_frac_rest" and _other(r) for r in group])
            ax.errorbar(x, y, xerr=err, color=colour, lw=1.5, capsize=3, zorder=2)
            ax.plot(x[~hollow], y[~hollow], ls="none", marker=marker, ms=6, color=colour,
                    zorder=3, label=name)
            ax.plot(x[hollow], y[hollow], ls="none", marker=marker, ms=6, mfc="white",
                    mec=colour, mew=1.5, zorder=3, label=None if (~hollow).any() else name)
            # Uniform labels below the points, adaptive ones above; the two
            # adaptive curves coincide where the higher maximum level is never
            # reached, so their labels go to opposite sides.
            if group[0]["kind"] == "uniform":
                offset, align = (6, -12), "left"
            elif colour == "C3":
                offset, align = (6, 5), "left"
            else:
                offset, align = (-6, 5), "right"
            for r, xi, yi in zip(group, x, y):
                text = (f"L{r['level']}" if r["kind"] == "uniform"
                        else f"{r['refine_threshold_m'] * 1e3:g} mm")
                ax.annotate(text, (xi, yi), textcoords="offset points", xytext=offset,
                            ha=align, fontsize=8, color=colour)
        ax.axvline(ref["wall_per_sim_s_median"], color="0.4", ls="--", lw=1)
        ax.annotate(f"reference L{ref['level']}\n(error 0)", (ref["wall_per_sim_s_median"], 0.5),
                    xycoords=("data", "axes fraction"), textcoords="offset points",
                    xytext=(-4, 0), ha="right", fontsize=8, color="0.3")
        ax.axvline(1.0, color="0.7", ls=":", lw=1)
        ax.annotate("real time", (1.0, 0.02), xycoords=("data", "axes fraction"),
                    textcoords="offset points", xytext=(3, 0), fontsize=8, color="0.5")
        if half is not None and half[key] > 0:
            ax.axhline(half[key], color="C2", ls="-.", lw=1)
            ax.annotate(f"reference at h vs at h/2: {100 * half[key]:.2g} % of side",
                        (0.02, half[key]), xycoords=("axes fraction", "data"),
                        textcoords="offset points", xytext=(0, 3), fontsize=8, color="C2")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.margins(x=0.12)                  # room for the labels of the end points
        ax.set_xlabel("cost: wall seconds per simulated second (median, bar = min–max), one core")
        ax.set_ylabel("RMS distance from reference / cloth side")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=8, loc="best")
    fig.suptitle(f"{summary['scene']}: error against cost, {summary['duration']:g} s simulated, "
                 f"h = {summary['time_step']:.4g} s, reference uniform L{ref['level']}",
                 fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# --------------------------------------------------------------------------
# Markdown: tables and a paragraph computed from the numbers.
# --------------------------------------------------------------------------

def _pct(x, digits=2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{100 * x:.{digits}g} %" if x < 0.1 else f"{100 * x:.1f} %"


def _cost_text(r: dict) -> str:
    return (f"{r['wall_per_sim_s_median']:.3g} ({r['wall_per_sim_s_min']:.3g}–"
            f"{r['wall_per_sim_s_max']:.3g})")


def _uniform_curve_error(rows: list[dict], key: str, cost: float) -> tuple[float | None, str]:
    """Error of the uniform curve at ``cost`` (s/s), log–log interpolated.

    Between two measured uniform levels (sorted by cost, reference excluded:
    its error is 0) the curve is a straight line in log–log.  Returns
    ``(error, where)``; ``error`` is None outside the measured range.
    """
    pts = sorted((r["wall_per_sim_s_median"], r[key]) for r in rows
                 if r["kind"] == "uniform" and r[key] > 0)
    if not pts:
        return None, "no uniform level with a non-zero error"
    if cost < pts[0][0]:
        return None, "cheaper than every uniform level"
    if cost > pts[-1][0]:
        return None, "dearer than every uniform level but the reference"
    for (c0, e0), (c1, e1) in zip(pts, pts[1:]):
        if c0 <= cost <= c1:
            f = 0.0 if c1 == c0 else math.log(cost / c0) / math.log(c1 / c0)
            return math.exp((1 - f) * math.log(e0) + f * math.log(e1)), "interpolated"
    return pts[0][1], "at a measured level"


def _compare_to_uniform(rows: list[dict], key: str) -> list[dict]:
    """For each adaptive row, its standing against the uniform levels on ``key``.

    Measured points only, for the verdict: ``dominates`` are the uniform levels
    (reference included) that cost at least as much and are less accurate;
    ``dominated_by`` those that cost at most as much and are at least as
    accurate (``within_spread`` when all of those overlap the adaptive run's
    min–max cost, i.e. the timing cannot separate them).  Neither is a
    trade-off.  ``curve_ratio`` is the uniform curve's error at the same cost
    over the adaptive error (> 1: adaptive more accurate at equal cost).
    """
    uniform = [r for r in rows if r["kind"] in ("uniform", "reference")]
    out = []
    for a in sorted((r for r in rows if r["kind"] == "adaptive"),
                    key=lambda r: (r["level"], r["refine_threshold_m"])):
        cost, err = a["wall_per_sim_s_median"], a[key]
        dominates = [u for u in uniform if u["wall_per_sim_s_median"] >= cost and u[key] > err]
        dominated = [u for u in uniform if u["wall_per_sim_s_median"] <= cost and u[key] <= err]

        def overlap(u):
            return (u["wall_per_sim_s_min"] <= a["wall_per_sim_s_max"]
                    and a["wall_per_sim_s_min"] <= u["wall_per_sim_s_max"])
        curve, where = _uniform_curve_error(rows, key, cost)
        out.append(dict(
            row=a, dominates=dominates, dominated_by=dominated,
            within_spread=bool(dominated) and all(overlap(u) for u in dominated),
            curve_error=curve, curve_where=where,
            curve_ratio=(curve / err) if (curve is not None and err > 0) else None))
    return out


def _levels(us: list[dict], key: str = "") -> str:
    mark = lambda u: " †" if key == "rms_frac_rest" and _other(u) else ""  # noqa: E731
    return ", ".join(f"L{u['level']}{mark(u)}" for u in sorted(us, key=lambda u: u["level"]))


def _comparison_table(rows: list[dict], key: str) -> list[str]:
    body = []
    for c in _compare_to_uniform(rows, key):
        a = c["row"]
        if c["dominated_by"]:
            verdict = "dominated by uniform " + _levels(c["dominated_by"], key)
            if c["within_spread"]:
                verdict += " (cost within the timing spread)"
        elif c["dominates"]:
            verdict = "dominates uniform " + _levels(c["dominates"], key)
        else:
            verdict = "trade-off (no uniform level is better in both)"
        curve = (f"{_pct(c['curve_error'])} ({c['curve_ratio']:.2g}×)"
                 if c["curve_ratio"] is not None else c["curve_where"])
        mark = " †" if key == "rms_frac_rest" and _other(a) else ""
        body.append([a["label"] + mark, _cost_text(a), _pct(a[key]), curve, verdict])
    return _table(["adaptive run", "wall s / sim s", "RMS / side",
                   "uniform curve at that cost (its error / adaptive error)", "verdict"], body)


def _verdict_sentences(rows: list[dict], key: str, what: str) -> str:
    comps = _compare_to_uniform(rows, key)
    below = [c for c in comps if c["curve_ratio"] is not None and c["curve_ratio"] > 1]
    above = [c for c in comps if c["curve_ratio"] is not None and c["curve_ratio"] <= 1]
    wins = [c for c in comps if c["dominates"] and not c["dominated_by"]]
    losses = [c for c in comps if c["dominated_by"]]
    name = lambda c: (c["row"]["label"].replace("adaptive ", "")  # noqa: E731
                      + (" †" if key == "rms_frac_rest" and _other(c["row"]) else ""))
    parts = [f"**{what}:** "]
    if wins:
        parts.append("the adaptive mesh dominates some uniform level (cheaper *and* more "
                     "accurate) at " + "; ".join(
                         f"{name(c)} (over uniform {_levels(c['dominates'], key)})" for c in wins)
                     + ". ")
    else:
        parts.append("no adaptive run is both cheaper and more accurate than any uniform "
                     "level. ")
    if losses:
        parts.append("A uniform level is both cheaper and at least as accurate as "
                     + "; ".join(f"{name(c)} (uniform {_levels(c['dominated_by'], key)}"
                                 + (", within the timing spread" if c["within_spread"] else "")
                                 + ")" for c in losses) + ". ")
    if below or above:
        parts.append(f"Against the log–log interpolated uniform curve, {len(below)} of "
                     f"{len(below) + len(above)} adaptive runs inside its cost range lie below "
                     "it (more accurate at equal cost)"
                     + (": " + ", ".join(f"{name(c)} {c['curve_ratio']:.2g}×" for c in below)
                        if below else "")
                     + ("; above it: " + ", ".join(f"{name(c)} {c['curve_ratio']:.2g}×"
                                                    for c in above) if above else "")
                     + ".")
    return "".join(parts)


def _why_table(rows: list[dict]) -> list[str]:
    """Triangles bought and cost per triangle-step, adaptive against the uniform
    level of nearest cost: why equal cost buys fewer triangles."""
    uni = [r for r in rows if r["kind"] in ("uniform", "reference")]
    ada = sorted((r for r in rows if r["kind"] == "adaptive"),
                 key=lambda r: (r["level"], r["refine_threshold_m"]))
    if not uni or not ada:
        return []

    def per_tri(r):         # µs of wall time per triangle per step
        return 1e6 * r["wall_per_sim_s_median"] * r["time_step_s"] / max(r["triangles_mean"], 1)
    body = []
    for a in ada:
        near = min(uni, key=lambda u: abs(math.log(u["wall_per_sim_s_median"]
                                                   / a["wall_per_sim_s_median"])))
        body.append([a["label"], f"{a['triangles_mean']:.0f} / {a['triangles_max']}",
                     f"{per_tri(a):.1f}", f"{a['cg_iterations_per_step']:.0f}",
                     _pct(a["lod_share_median"]), _pct(a["unattributed_share_median"]),
                     near["label"], f"{near['triangles_mean']:.0f}", f"{per_tri(near):.1f}",
                     f"{near['cg_iterations_per_step']:.0f}",
                     _pct(near["unattributed_share_median"])])
    return _table(["adaptive run", "triangles mean / max", "µs per triangle-step",
                   "CG it. / step", "LOD share", "unattributed", "uniform of nearest cost",
                   "triangles", "µs per triangle-step", "CG it. / step", "unattributed"], body)


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def _other(row: dict) -> bool:
    return row["kind"] != "reference" and bool(row.get("rest_other_shape"))


def _same_computations(rows: list[dict]) -> list[tuple[dict, dict]]:
    """Adaptive pairs (same threshold, different maximum level) that did the
    same work and got the same errors: the higher maximum was never reached."""
    ada = sorted((r for r in rows if r["kind"] == "adaptive"),
                 key=lambda r: (r["refine_threshold_m"], r["level"]))
    pairs = []
    for a, b in zip(ada, ada[1:]):
        if (a["refine_threshold_m"] == b["refine_threshold_m"]
                and a["vertex_steps"] == b["vertex_steps"]
                and a["cg_iterations"] == b["cg_iterations"]
                and a["rms_frac_motion"] == b["rms_frac_motion"]
                and a["rms_frac_rest"] == b["rms_frac_rest"]):
            pairs.append((a, b))
    return pairs


def _rest_shape_section(rows: list[dict]) -> list[str]:
    """Where each run at rest is farthest from the reference, and which way."""
    body = []
    for r in rows:
        if r["kind"] == "reference":
            continue
        body.append([r["label"] + (" †" if _other(r) else ""), _pct(r["rms_frac_rest"]),
                     _pct(r["max_frac_rest"]), _pct(r["max_frac_motion"]),
                     f"({r['rest_worst_u_m']:.3g}, {r['rest_worst_v_m']:.3g})",
                     ", ".join(f"{1e3 * r[f'rest_worst_d{c}_m']:+.1f}" for c in "xyz")])
    others = [r for r in rows if _other(r)]
    text = ("**At rest: which shape.** For each run, the material point (u, v) farthest from "
            "the reference at rest and the offset there. ")
    if others:
        text += (f"{len(others)} run{'s' if len(others) > 1 else ''} (†) "
                 f"{'have' if len(others) > 1 else 'has'} the largest distance at rest over "
                 "twice the largest while moving: not a small drift but a different "
                 "equilibrium (e.g. a fold that buckled the other way; the offsets show where "
                 "and which way). For those, the at-rest verdicts above compare which shape a "
                 "run fell into, not how accurate its mesh is.")
    else:
        text += "No run settled into a visibly different shape."
    return ([text, ""] + _table(["run", "RMS at rest", "max at rest", "max during motion",
                                  "farthest point (u, v) m", "offset there (x, y, z) mm"],
                                 body) + [""])


def _markdown(result: dict) -> str:
    s, m, rows = result["settings"], result["machine"], result["rows"]
    times = s["times"]
    tags = [_time_tag(t) for t in times] + ["rest"]
    ref = next(r for r in rows if r["kind"] == "reference")
    half = next((r for r in rows if r["kind"] == "half_step"), None)
    rest = result["rest"]
    md = [f"# cloth-lod bench: {s['scene']}", ""]
    md += [f"Command: `{s['command']}` (or `python -m cloth_lod_ros.tools.bench` with the same "
           "arguments)  ",
           f"Machine: {m['cpu_model']}, {m['logical_cpus']} logical CPUs (each run pinned to "
           f"CPU {m['pinned_cpu']}, one thread), {m['platform']}; Python {m['python']}, "
           f"numpy {m['numpy']}, scipy {m['scipy']}; commit {m['git_commit'] or '?'}; "
           f"{m['date']}.  ",
           f"Wall time of the whole benchmark: {result['wall_s'] / 60:.1f} min; 1-minute load "
           f"average during the runs {result['load_min']:.2f}–{result['load_max']:.2f} "
           "(the machine is shared; a load above 1 on 2 CPUs means other work competed for "
           "the cores, so compare the min–max ranges, not only the medians).", ""]
    md += ["## Set-up", "",
           f"- Scene `{s['scene']}`, {s['duration']:g} s simulated, h = {s['time_step']:.6g} s; "
           f"cloth side {s['side_m']:g} m (0.1 % of the side = {s['side_m']:g} mm).",
           f"- Reference: uniform level {s['reference_level']}, same h. "
           + s["reference_note"],
           f"- Error: RMS and max distance from the reference over a {s['grid']} × {s['grid']} "
           f"grid of material points, as a fraction of the side, at t = "
           + ", ".join(f"{t:.4g}" for t in times) + " s and at rest. \"During motion\" is the "
           "RMS over all points and those times.",
           f"- At rest: the first time after {s['duration']:g} s at which the reference's "
           f"kinetic energy per unit mass stayed below {s['rest_threshold']:g} J/kg for "
           f"{s['rest_window']:g} s, capped at {s['rest_cap']:g} s: "
           + (f"t = {rest['time']:g} s." if rest["at_rest"] else
              f"**not reached by the cap**; sampled at t = {rest['time']:g} s "
              f"(reference kinetic energy {rest['ke_per_mass']:.2g} J/kg).")
           + " Every run is sampled at that time; its own kinetic energy there is in the "
           "CSV (`ke_per_mass_at_rest`).",
           f"- Cost over the first {s['duration']:g} s only: wall seconds per simulated second "
           f"(median and min–max of {s['repeats']} runs, each a fresh process pinned to one "
           "CPU, all thread pools at 1), vertex-steps, CG iterations, share of wall time in "
           "LOD (criterion, splits/merges, refresh of compact arrays). The reference at h/2 "
           "runs once (it is there for its error, not its cost).",
           f"- Adaptive runs start from level {s['initial_level']} and refine where the "
           "deviation d exceeds the threshold; coarsen threshold = "
           f"{s['coarsen_ratio']:g} × threshold (the scene's ratio)."]
    md.append(f"- The bench's clock around `ClothSim.step()` read at most "
              f"{_pct(max(r['timing_overhead_share_max'] for r in rows))} more than the "
              "step's own clock (`StepStats.step_ms`): sampling and bookkeeping are outside "
              "the timed calls.")
    if any(r["repeat_max_deviation_m"] > 0 for r in rows):
        md.append("- **Repeats differ** (see `repeat_max_deviation_m`): runs are not "
                  "deterministic.")
    else:
        md.append("- Every repeat reproduced the first one's samples bit for bit.")
    md.append("")
    if half is not None:
        md += ["## What \"converged\" means", "",
               f"Distance of the reference (uniform L{ref['level']}, h) from the same mesh at "
               f"h/2 (implicit Euler's numerical damping depends on h):", ""]
        md += _table(["t"] + [t.replace("s", " s") if t != "rest" else "rest" for t in tags],
                     [["RMS / side"] + [_pct(half[f"rms_frac_{t}"]) for t in tags],
                      ["max / side"] + [_pct(half[f"max_frac_{t}"]) for t in tags]])
        md += ["", "Errors below are spatial (mesh) errors at fixed h; where they are smaller "
               "than this row, the time step, not the mesh, limits the accuracy."]
        finest = max((r for r in rows if r["kind"] == "uniform"), key=lambda r: r["level"],
                     default=None)
        if finest is not None and finest["rms_frac_motion"] > 0:
            md[-1] += (f" During motion, halving h moves the reference "
                       f"{half['rms_frac_motion'] / finest['rms_frac_motion']:.3g}× as far as "
                       f"refining from uniform L{finest['level']} to L{ref['level']} does "
                       f"({_pct(half['rms_frac_motion'])} against "
                       f"{_pct(finest['rms_frac_motion'])} RMS); at rest "
                       f"{_pct(half['rms_frac_rest'])} against {_pct(finest['rms_frac_rest'])}.")
        md.append("")
    md += ["## Results", ""]
    header = (["run", "wall s / sim s", "ms / step", "CPU s / sim s", "vertex-steps",
               "CG it. (per step)", "triangles mean / max", "LOD share"]
              + [f"RMS {t.replace('s', ' s') if t != 'rest' else 'at rest'}" for t in tags]
              + ["RMS motion", "max motion", "max at rest"])
    body = []
    for r in rows:
        if r["kind"] == "half_step":
            continue
        body.append([r["label"], _cost_text(r), f"{r['ms_per_step_median']:.3g}",
                     f"{r['cpu_per_sim_s_median']:.3g}", f"{r['vertex_steps']:,}",
                     f"{r['cg_iterations']:,} ({r['cg_iterations_per_step']:.0f})",
                     f"{r['triangles_mean']:.0f} / {r['triangles_max']}",
                     _pct(r["lod_share_median"]) if r["kind"] == "adaptive" else "—"]
                    + [_pct(r[f"rms_frac_{t}"]) + (" †" if t == "rest" and _other(r) else "")
                       for t in tags]
                    + [_pct(r["rms_frac_motion"]), _pct(r["max_frac_motion"]),
                       _pct(r["max_frac_rest"])])
    md += _table(header, body)
    if any(_other(r) for r in rows):
        md += ["", "† settled into another shape than the reference (its largest distance at "
               "rest is more than twice its largest distance during motion); see "
               "\"At rest: which shape\" below."]
    same = _same_computations(rows)
    if same:
        md += ["", "Same computation, different labels: " + "; ".join(
            f"{b['label']} never refined past what {a['label']} did (same vertex-steps, CG "
            f"iterations and errors), so the gap between their costs, "
            f"{a['wall_per_sim_s_median']:.3g} and {b['wall_per_sim_s_median']:.3g} s per "
            f"simulated second, is timing noise" for a, b in same)
            + ". That is how far apart two measurements of one computation came on this "
            "machine."]
    md += ["", "![error against cost](bench.png)", ""]
    paper = result.get("paper")
    md += ["## The paper's comparison on our code", ""]
    if paper:
        md += [f"Mean time per step over the first {s['duration']:g} s (the paper's \"frame\"), "
               f"adaptive (max level {paper['level']}, threshold "
               f"{paper['threshold'] * 1e3:g} mm, as in the scene) against uniform level "
               f"{paper['level']} ({paper['grid']} × {paper['grid']} particles), median "
               "(min–max) of the repeats; the ratio is computed per round (runs back to back).",
               ""]
        md += _table(
            ["", "adaptive ms / step", "uniform ms / step", "ratio", "LOD share",
             "adaptive RMS motion / rest", "uniform RMS motion / rest"],
            [["paper (2003 hardware)", f"{PAPER['adaptive_ms']:.1f}",
              f"{PAPER['uniform_ms']:.1f}", f"{PAPER['ratio']:.1f}×", "~3 %", "not given",
              "not given"],
             ["this code", paper["adaptive_ms_text"], paper["uniform_ms_text"],
              paper["ratio_text"],
              f"{_pct(paper['lod_share'])} (≤ {_pct(paper['lod_share_upper'])})",
              f"{_pct(paper['adaptive_rms_motion'])} / {_pct(paper['adaptive_rms_rest'])}",
              f"{_pct(paper['uniform_rms_motion'])} / {_pct(paper['uniform_rms_rest'])}"]])
        md += ["", "LOD share: as `StepStats.lod_ms` books it; in brackets, plus the "
               "adaptive run's unattributed share beyond the uniform run's (mostly the "
               "criterion's force evaluation on steps where the mesh changes). Errors: RMS "
               "distance from the reference, as a fraction of the side.", ""]
    else:
        md += ["Not available: the run needs the scene's level among `--levels` and "
               "`--max-levels` and its refine threshold among `--thresholds`.", ""]
    md += ["## Does adaptive beat uniform?", "",
           "Verdicts use measured points only; \"dominates\" means cheaper (median wall "
           "time) *and* more accurate. The uniform curve column interpolates between "
           "measured uniform levels in log–log.", ""]
    for key, what in (("rms_frac_motion", "During motion"), ("rms_frac_rest", "At rest")):
        md += [_verdict_sentences(rows, key, what), ""] + _comparison_table(rows, key) + [""]
    md += _rest_shape_section(rows)
    why = _why_table(rows)
    if why:
        md += ["Where the time goes: the triangles each run simulates, and what a "
               "triangle-step costs (wall time per step / mean triangles), against the "
               "uniform level of nearest cost. \"Unattributed\" is step time that "
               "`StepStats` books to none of LOD, forces, assembly and solve: energies and "
               "statistics in every run, and with LOD on also the criterion's force "
               "evaluation on steps where the mesh then changes (the solver evaluates the new "
               "mesh again and books only that one). The LOD share is therefore a lower "
               "bound; LOD share + the adaptive run's extra unattributed share is about the "
               "upper one.", ""] + why + [""]
    if half is not None:
        md += [f"For scale: the reference itself moves {_pct(half['rms_frac_motion'])} RMS "
               "during motion when the time step is halved, "
               f"and {_pct(half['rms_frac_rest'])} at rest.", ""]
    md += ["Files: `bench.csv` (one row per configuration), `bench.json` (the same rows plus "
           "machine, settings and every repeat), `bench.png`.", ""]
    return "\n".join(md)


# --------------------------------------------------------------------------
# Command line.
# --------------------------------------------------------------------------
