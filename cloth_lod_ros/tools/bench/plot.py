"""``cloth-lod bench`` output files: the CSV and the error-against-cost plot."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..reference import SAME_STEP_LABEL
from .analysis import families, other, uniform_rows

__all__ = ["write_csv", "plot"]


def write_csv(path: Path, rows: list[dict]) -> None:
    fields = list(rows[0])
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            # repr() of a float reads back to the same float.
            writer.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v)
                             for k, v in row.items()})


def plot(path: Path, result: dict) -> None:
    """Error against cost, one colour per family: uniform levels joined by a
    line (labelled by level), adaptive runs as stars; the reference's own
    error as horizontal lines."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s, rows = result["settings"], result["rows"]
    ref = result["reference"]
    converged = ref["mode"] == "converged"
    own = ref.get("own_error") or {}
    panels = [("rms_frac_motion", "motion", "during motion: RMS over t = "
               + ", ".join(f"{t:.3g}" for t in s["times"]) + " s"),
              ("rms_frac_rest", "rest", f"at rest (t = {result['rest']['time']:.3g} s"
               + ("" if result["rest"]["at_rest"] else ": the cap, not at rest")
               + "); hollow: settled into another shape")]
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.6))
    colours = {}
    for ax, (key, own_key, title) in zip(axes, panels):
        for i, (fam, fam_rows) in enumerate(families(rows)):
            colour = colours.setdefault(fam, f"C{i % 10}")
            name = fam_rows[0]["label"].rsplit(", uniform", 1)[0].rsplit(", adaptive", 1)[0]
            for group, marker, size, line in (
                    (uniform_rows(fam_rows), "o", 5, "-"),
                    ([r for r in fam_rows if r["kind"] == "adaptive"], "*", 12, "none")):
                group = sorted((r for r in group if r[key] > 0),
                               key=lambda r: (r["level"], r["wall_per_sim_s_median"]))
                if not group:
                    continue
                x = np.array([r["wall_per_sim_s_median"] for r in group])
                y = np.array([r[key] for r in group])
                err = np.array([[r["wall_per_sim_s_median"] - r["wall_per_sim_s_min"]
                                 for r in group],
                                [r["wall_per_sim_s_max"] - r["wall_per_sim_s_median"]
                                 for r in group]])
                hollow = np.array([key == "rms_frac_rest" and other(r) for r in group])
                ax.errorbar(x, y, xerr=err, color=colour, ls=line, lw=1.4, capsize=2,
                            zorder=2)
                ax.plot(x[~hollow], y[~hollow], ls="none", marker=marker, ms=size,
                        color=colour, zorder=3, label=name if marker == "o" else None)
                ax.plot(x[hollow], y[hollow], ls="none", marker=marker, ms=size, mfc="white",
                        mec=colour, mew=1.3, zorder=3)
                for r, xi, yi in zip(group, x, y):
                    text = (f"L{r['level']}" if marker == "o" else
                            f"A{r['level']}" + (f" {r['refine_threshold_m'] * 1e3:g}mm"
                                                if len(s["thresholds"]) > 1 else ""))
                    ax.annotate(text, (xi, yi), textcoords="offset points",
                                xytext=(4, -10 if marker == "o" else 5), fontsize=7,
                                color=colour)
        ax.plot([], [], ls="none", marker="*", ms=10, color="0.3",
                label="adaptive (A = max level)")
        if converged:
            for what, style in (("time", "--"), ("mesh", ":")):
                value = own.get(own_key, {}).get(f"{what}_rms")
                if value:
                    ax.axhline(value, color="0.25", ls=style, lw=1,
                               label=f"reference's own {what} error")
        ax.axvline(1.0, color="0.7", ls=":", lw=1)
        ax.annotate("real time", (1.0, 0.02), xycoords=("data", "axes fraction"),
                    textcoords="offset points", xytext=(3, 0), fontsize=8, color="0.5")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.margins(x=0.12)
        ax.set_xlabel("cost: wall seconds per simulated second (median, bar = min–max), one core")
        ax.set_ylabel("RMS distance from the " + ("converged motion" if converged
                                                   else "reference") + " / cloth side")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.25)
    axes[0].legend(fontsize=7, loc="best")
    what = (f"converged reference: uniform L{ref['level']}, sdirk2, h/{ref['divisor']:g}"
            if converged else f"{SAME_STEP_LABEL}: uniform L{ref['level']}, same integrator")
    fig.suptitle(f"{s['scene']}: error against cost, {s['duration']:g} s simulated, frame "
                 f"h = {s['time_step']:.4g} s; {what}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
