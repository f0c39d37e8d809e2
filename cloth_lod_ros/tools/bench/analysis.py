"""``cloth-lod bench``: comparisons computed from the rows, and small formatting helpers.

Rows are compared within a *family* (one integrator setting): the adaptive
runs against the uniform levels of the same family, so that the verdicts
measure the mesh, not the time integration; :func:`pareto` looks across all
of them.
"""

from __future__ import annotations

import math

__all__ = ["time_tag", "pct", "table", "other", "families", "uniform_rows", "pareto",
           "compare_to_uniform", "verdict_sentences", "why_table", "same_computations"]


def time_tag(t: float) -> str:
    return f"{t:.4g}s"


def pct(x, digits=2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{100 * x:.{digits}g} %" if x < 0.1 else f"{100 * x:.1f} %"


def table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def other(row: dict) -> bool:
    """Settled into another resting shape than the reference (†)."""
    return row["kind"] != "same_step" and bool(row.get("rest_other_shape"))


def families(rows: list[dict]) -> list[tuple[str, list[dict]]]:
    """``(family key, its rows)`` in the order the families were asked for."""
    order: dict[str, list[dict]] = {}
    for r in rows:
        order.setdefault(r["family"], []).append(r)
    return list(order.items())


def uniform_rows(rows: list[dict]) -> list[dict]:
    """Uniform runs, the same-step reference rows included."""
    return [r for r in rows if r["kind"] in ("uniform", "same_step")]


def pareto(rows: list[dict], key: str) -> list[dict]:
    """The rows no other row beats on both cost (median wall time) and ``key``
    error, cheapest first."""
    front = []
    for r in rows:
        cost, err = r["wall_per_sim_s_median"], r[key]
        if not any(o is not r and o["wall_per_sim_s_median"] <= cost and o[key] <= err
                   and (o["wall_per_sim_s_median"] < cost or o[key] < err) for o in rows):
            front.append(r)
    return sorted(front, key=lambda r: r["wall_per_sim_s_median"])


def _uniform_curve_error(rows: list[dict], key: str, cost: float) -> tuple[float | None, str]:
    """Error of one family's uniform curve at ``cost`` (s/s), log–log interpolated.

    Between two measured uniform levels (sorted by cost, rows with error 0
    excluded) the curve is a straight line in log–log.  Returns ``(error,
    where)``; ``error`` is None outside the measured range.
    """
    pts = sorted((r["wall_per_sim_s_median"], r[key]) for r in uniform_rows(rows) if r[key] > 0)
    if not pts:
        return None, "no uniform level with a non-zero error"
    if cost < pts[0][0]:
        return None, "cheaper than every uniform level"
    if cost > pts[-1][0]:
        return None, "dearer than every uniform level"
    for (c0, e0), (c1, e1) in zip(pts, pts[1:]):
        if c0 <= cost <= c1:
            f = 0.0 if c1 == c0 else math.log(cost / c0) / math.log(c1 / c0)
            return math.exp((1 - f) * math.log(e0) + f * math.log(e1)), "interpolated"
    return pts[0][1], "at a measured level"


def compare_to_uniform(rows: list[dict], key: str) -> list[dict]:
    """For each adaptive row, its standing against the uniform levels of its family.

    Measured points only, for the verdict: ``dominates`` are the uniform levels
    that cost at least as much and are less accurate; ``dominated_by`` those
    that cost at most as much and are at least as accurate (``within_spread``
    when all of those overlap the adaptive run's min–max cost, i.e. the timing
    cannot separate them).  Neither is a trade-off.  ``curve_ratio`` is the
    uniform curve's error at the same cost over the adaptive error (> 1:
    adaptive more accurate at equal cost).
    """
    out = []
    for _, fam_rows in families(rows):
        uniform = uniform_rows(fam_rows)
        for a in sorted((r for r in fam_rows if r["kind"] == "adaptive"),
                        key=lambda r: (r["level"], r["refine_threshold_m"])):
            cost, err = a["wall_per_sim_s_median"], a[key]
            dominates = [u for u in uniform
                         if u["wall_per_sim_s_median"] >= cost and u[key] > err]
            dominated = [u for u in uniform
                         if u["wall_per_sim_s_median"] <= cost and u[key] <= err]

            def overlap(u):
                return (u["wall_per_sim_s_min"] <= a["wall_per_sim_s_max"]
                        and a["wall_per_sim_s_min"] <= u["wall_per_sim_s_max"])
            curve, where = _uniform_curve_error(fam_rows, key, cost)
            out.append(dict(
                row=a, dominates=dominates, dominated_by=dominated,
                within_spread=bool(dominated) and all(overlap(u) for u in dominated),
                curve_error=curve, curve_where=where,
                curve_ratio=(curve / err) if (curve is not None and err > 0) else None))
    return out


def levels_text(us: list[dict], key: str = "") -> str:
    mark = lambda u: " †" if key == "rms_frac_rest" and other(u) else ""  # noqa: E731
    return ", ".join(f"L{u['level']}{mark(u)}" for u in sorted(us, key=lambda u: u["level"]))


def comparison_table(rows: list[dict], key: str) -> list[str]:
    body = []
    for c in compare_to_uniform(rows, key):
        a = c["row"]
        if c["dominated_by"]:
            verdict = "dominated by uniform " + levels_text(c["dominated_by"], key)
            if c["within_spread"]:
                verdict += " (cost within the timing spread)"
        elif c["dominates"]:
            verdict = "dominates uniform " + levels_text(c["dominates"], key)
        else:
            verdict = "trade-off (no uniform level is better in both)"
        curve = (f"{pct(c['curve_error'])} ({c['curve_ratio']:.2g}×)"
                 if c["curve_error"] is not None and c["curve_ratio"] is not None
                 else c["curve_where"])
        body.append([a["label"] + (" †" if key == "rms_frac_rest" and other(a) else ""),
                     f"{a['wall_per_sim_s_median']:.3g}", pct(a[key]), curve, verdict])
    return table(["adaptive run", "wall s / sim s", "RMS error",
                  "same family's uniform curve at that cost (ratio)", "verdict"], body)


def verdict_sentences(rows: list[dict], key: str, what: str) -> str:
    comps = compare_to_uniform(rows, key)
    below = [c for c in comps if c["curve_ratio"] is not None and c["curve_ratio"] > 1]
    above = [c for c in comps if c["curve_ratio"] is not None and c["curve_ratio"] <= 1]
    wins = [c for c in comps if c["dominates"] and not c["dominated_by"]]
    losses = [c for c in comps if c["dominated_by"]]
    name = lambda c: (c["row"]["label"]  # noqa: E731
                      + (" †" if key == "rms_frac_rest" and other(c["row"]) else ""))
    parts = [f"**{what}:** "]
    if wins:
        parts.append("the adaptive mesh dominates some uniform level of its family (cheaper "
                     "*and* more accurate) at " + "; ".join(
                         f"{name(c)} (over uniform {levels_text(c['dominates'], key)})"
                         for c in wins) + ". ")
    else:
        parts.append("no adaptive run is both cheaper and more accurate than a uniform "
                     "level of its family. ")
    if losses:
        parts.append("A uniform level of the same family is both cheaper and at least as "
                     "accurate as " + "; ".join(
                         f"{name(c)} (uniform {levels_text(c['dominated_by'], key)}"
                         + (", within the timing spread" if c["within_spread"] else "")
                         + ")" for c in losses) + ". ")
    if below or above:
        parts.append(f"Against the log–log interpolated uniform curve of the same family, "
                     f"{len(below)} of {len(below) + len(above)} adaptive runs inside its cost "
                     "range lie below it (more accurate at equal cost)"
                     + (": " + ", ".join(f"{name(c)} {c['curve_ratio']:.2g}×" for c in below)
                        if below else "")
                     + ("; above it: " + ", ".join(f"{name(c)} {c['curve_ratio']:.2g}×"
                                                    for c in above) if above else "")
                     + ".")
    return "".join(parts)


def why_table(rows: list[dict]) -> list[str]:
    """Triangles bought and cost per triangle-step, adaptive against the uniform
    level of nearest cost in the same family."""
    body = []

    def per_tri(r):         # µs of wall time per triangle per frame
        return 1e6 * r["wall_per_sim_s_median"] * r["time_step_s"] / max(r["triangles_mean"], 1)
    for _, fam_rows in families(rows):
        uni = uniform_rows(fam_rows)
        for a in sorted((r for r in fam_rows if r["kind"] == "adaptive"),
                        key=lambda r: (r["level"], r["refine_threshold_m"])):
            if not uni:
                continue
            near = min(uni, key=lambda u: abs(math.log(u["wall_per_sim_s_median"]
                                                       / a["wall_per_sim_s_median"])))
            body.append([a["label"], f"{a['triangles_mean']:.0f} / {a['triangles_max']}",
                         f"{per_tri(a):.1f}", f"{a['cg_iterations_per_frame']:.0f}",
                         pct(a["lod_share_median"]), pct(a["unattributed_share_median"]),
                         f"L{near['level']}", f"{near['triangles_mean']:.0f}",
                         f"{per_tri(near):.1f}", f"{near['cg_iterations_per_frame']:.0f}",
                         pct(near["unattributed_share_median"])])
    if not body:
        return []
    return table(["adaptive run", "triangles mean / max", "µs per triangle-frame",
                  "CG it. / frame", "LOD share", "unattributed", "uniform of nearest cost",
                  "triangles", "µs per triangle-frame", "CG it. / frame", "unattributed"], body)


def same_computations(rows: list[dict]) -> list[tuple[dict, dict]]:
    """Adaptive pairs of one family (same threshold, different maximum level)
    that did the same work and got the same errors: the higher maximum was
    never reached."""
    pairs = []
    for _, fam_rows in families(rows):
        ada = sorted((r for r in fam_rows if r["kind"] == "adaptive"),
                     key=lambda r: (r["refine_threshold_m"], r["level"]))
        for a, b in zip(ada, ada[1:]):
            if (a["refine_threshold_m"] == b["refine_threshold_m"]
                    and a["vertex_steps"] == b["vertex_steps"]
                    and a["cg_iterations"] == b["cg_iterations"]
                    and a["rms_frac_motion"] == b["rms_frac_motion"]
                    and a["rms_frac_rest"] == b["rms_frac_rest"]):
                pairs.append((a, b))
    return pairs


def rest_shape_section(rows: list[dict]) -> list[str]:
    """Where each run at rest is farthest from the reference, and which way."""
    body = []
    for r in rows:
        if r["kind"] == "same_step":
            continue
        body.append([r["label"] + (" †" if other(r) else ""), pct(r["rms_frac_rest"]),
                     pct(r["max_frac_rest"]), pct(r["max_frac_motion"]),
                     f"({r['rest_worst_u_m']:.3g}, {r['rest_worst_v_m']:.3g})",
                     ", ".join(f"{1e3 * r[f'rest_worst_d{c}_m']:+.1f}" for c in "xyz")])
    others = [r for r in rows if other(r)]
    text = ("**At rest: which shape.** For each run, the material point (u, v) farthest from "
            "the reference at rest and the offset there. ")
    if others:
        text += (f"{len(others)} run{'s' if len(others) > 1 else ''} (†) "
                 f"{'show' if len(others) > 1 else 'shows'} the signs of a different "
                 "equilibrium (the hanging cloth has two; the offsets show where and which "
                 "way): for those, the at-rest numbers compare which shape a run fell into, "
                 "not how accurate it is. The test is a heuristic: runs with the same "
                 "farthest point and offset as a † run are likely in the same shape.")
    else:
        text += "No run settled into a visibly different shape."
    return ([text, ""] + table(["run", "RMS at rest", "max at rest", "max during motion",
                                "farthest point (u, v) m", "offset there (x, y, z) mm"],
                               body) + [""])
