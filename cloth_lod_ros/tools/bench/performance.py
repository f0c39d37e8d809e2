"""``cloth-lod bench --report MD``: one Markdown page from the benchmark's output files.

The three benchmark modes each write a JSON file into ``--out``: ``bench.json``
(speed against error from the converged motion, design §5), ``scenes.json``
(``--scenes``: every built-in scene) and ``solvers.json`` (``--solvers``: the
linear-solver backends).  :func:`write_report` reads whichever of them a
directory holds and writes one page with, for each, the command that produced
it, the machine it ran on (CPU model, logical CPUs, platform, Python, numpy,
scipy and numba versions, as far as the file records them) and every row of
its table; the error-against-cost plot ``bench.png`` is linked relative to the
page.  Nothing is measured here: the page is a function of the files, so
``docs/performance.md`` is regenerated, never edited.

Files written before the suites recorded their command and full machine are
read too: a missing field is printed as "not recorded", and a suite's command
is rebuilt from what the file does record (its repeat count) and marked so.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from ..reference import SAME_STEP_LABEL
from .analysis import pct, table, time_tag
from .report import PAPER, own_error_line

__all__ = ["SOURCES", "anchor", "collect", "contact_table", "machine_line", "markdown", "write_report"]

#: The files a report is made of, in the order of its sections.
SOURCES = ("bench.json", "scenes.json", "solvers.json", "contact.json", "local.json")
NOT_RECORDED = "not recorded"
DEFAULT_REPEATS = 3


def collect(directory: Path) -> dict[str, dict]:
    """The benchmark results found in ``directory``, keyed by file stem
    (``bench``, ``scenes``, ``solvers``).  Raises ``ValueError`` for a file
    that exists but is not a benchmark result, ``FileNotFoundError`` when
    none exists."""
    found = {}
    for name in SOURCES:
        path = Path(directory) / name
        if not path.exists():
            continue
        try:
            data = json.loads(path.read_text())
            data["rows"], data["machine"]
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path} is not a cloth-lod bench result ({exc})") from None
        found[path.stem] = data
    if not found:
        raise FileNotFoundError(f"no benchmark results ({', '.join(SOURCES)}) in {directory}")
    return found


def machine_line(machine: dict) -> str:
    """The machine a result ran on, one line; fields the file lacks say so."""
    get = lambda key: machine.get(key) or NOT_RECORDED  # noqa: E731
    cpu = machine.get("cpu_model") or machine.get("processor") or NOT_RECORDED
    pinned = machine.get("pinned_cpu", machine.get("cpu"))
    return (f"Machine: CPU {cpu}; logical CPUs: {get('logical_cpus')}; every run pinned to CPU "
            f"{pinned if pinned is not None else NOT_RECORDED} with one thread; platform "
            f"{get('platform')}; Python {get('python')}, numpy {get('numpy')}, "
            f"scipy {get('scipy')}, numba {get('numba')}; date: {get('date')}.")


def _suite_command(result: dict, flag: str, out: str) -> str:
    """The command recorded in a ``--scenes``/``--solvers`` result, or one
    rebuilt from its repeat count (marked as such)."""
    if result.get("command"):
        return f"`{result['command']}`"
    repeats = result.get("repeats", DEFAULT_REPEATS)
    parts = ["cloth-lod bench", flag] + ([f"--repeats {repeats}"]
                                         if repeats != DEFAULT_REPEATS else [])
    return (f"`{' '.join(parts + [f'--out {out}'])}` (rebuilt: this file records no command; "
            "`--cpu` chooses the core)")


def _bench_section(result: dict, image: str) -> list[str]:
    s, rows = result["settings"], result["rows"]
    tags = [time_tag(t) for t in s["times"]] + ["rest"]
    head = lambda t: "at rest" if t == "rest" else t.replace("s", " s")  # noqa: E731
    reference = ("the converged motion" if result["reference"]["mode"] == "converged"
                 else f"a {SAME_STEP_LABEL}")
    rest = result.get("rest") or {}
    at_rest = "" if not rest else (f" (t = {rest['time']:g} s" + (
        ")" if rest.get("at_rest") else ", the cap: the reference was not at rest)"))
    times = ", ".join(f"{t:.4g}" for t in s["times"])
    md = ["## Speed against error: `cloth-lod bench`", "",
          f"Command: `{s['command']}`  ", machine_line(result["machine"]) + "  ",
          f"Wall time of the whole benchmark: {result.get('wall_s', 0) / 60:.1f} min; 1-minute "
          f"load average during the runs {result.get('load_min', 0):.2f}–"
          f"{result.get('load_max', 0):.2f}.", "",
          f"Scene `{s['scene']}`, {s['duration']:g} s simulated at frame period h = "
          f"{s['time_step']:.6g} s; {s['repeats']} repeats per run, each a fresh process "
          f"pinned to one CPU with every thread pool at one thread. Error: RMS distance from "
          f"{reference} over a {s['grid']} × {s['grid']} grid of material points, as a "
          f"fraction of the {s['side_m']:g} m side, at t = {times} s (\"during motion\": the "
          f"RMS over those times) and at rest{at_rest}. Cost: wall seconds per simulated "
          f"second over the first {s['duration']:g} s, median (min–max) of the repeats.", "",
          f"![error against cost: every run of the table]({image})", ""]
    body = [[r["label"]] + [pct(r[f"rms_frac_{t}"]) for t in tags]
            + [pct(r["rms_frac_motion"]),
               f"{r['wall_per_sim_s_median']:.3g} ({r['wall_per_sim_s_min']:.3g}–"
               f"{r['wall_per_sim_s_max']:.3g})",
               f"{r['ms_per_frame_median']:.3g}", f"{r['substeps_per_frame']:.2f}",
               f"{r['solves_per_frame']:.2f}", f"{r['triangles_mean']:.0f}",
               pct(r["lod_share_median"]) if r["kind"] == "adaptive" else "—"]
            for r in rows]
    md += table(["run"] + [f"RMS {head(t)}" for t in tags]
                + ["RMS during motion", "wall s / sim s", "ms / frame", "substeps / frame",
                   "solves / frame", "triangles (mean)", "LOD share"], body)
    md += ["", own_error_line(result), ""]
    paper = result.get("paper")
    if paper:
        md += ["The paper's own comparison (its §6: `baraff_witkin`, one step per frame, "
               f"adaptive with maximum level {paper['level']} against uniform level "
               f"{paper['level']}, {paper['grid']} × {paper['grid']} particles), mean time per "
               "frame over the same window:", ""]
        md += table(["", "adaptive ms / frame", "uniform ms / frame", "ratio", "LOD share"],
                    [["paper (2003 hardware)", f"{PAPER['adaptive_ms']:.1f}",
                      f"{PAPER['uniform_ms']:.1f}", f"{PAPER['ratio']:.1f}×", "~3 %"],
                     ["this code", paper["adaptive_ms_text"], paper["uniform_ms_text"],
                      paper["ratio_text"], pct(paper["lod_share"])]])
        md.append("")
    return md


def _scenes_section(result: dict, out: str) -> list[str]:
    md = ["## Every built-in scene: `cloth-lod bench --scenes`", "",
          f"Command: {_suite_command(result, '--scenes', out)}  ",
          machine_line(result["machine"]) + "  ",
          f"{result['repeats']} repeats per case in rounds, "
          f"{result.get('minutes', 0):.1f} min in all.", "",
          "Each case runs in a fresh process pinned to one CPU with one thread. ms / frame is "
          "the median wall time per frame, the real-time factor the frame period over it; the "
          "shares (of the simulator's own step time) and counts are those of the median-time "
          "repeat; \"× vs\" is the ratio to the case named, from the same session.", ""]
    body = []
    for r in result["rows"]:
        versus = "" if r.get("ratio_to_vs") is None else f"{r['ratio_to_vs']:.3f} × {r['vs']}"
        body.append([r["case"], r["lod"], f"{r['ms_per_frame']:.1f}",
                     f"{r['real_time_factor']:.2f}", versus, pct(r["lod_share"]),
                     pct(r["force_share"]), pct(r["solve_share"]),
                     pct(r["self_collision_share"]), f"{r['solves_per_frame']:.1f}",
                     f"{r['substeps_per_frame']:.2f}", f"{r['triangles_mean']:.0f}",
                     "+".join(r.get("solvers") or []) or "—"])
    md += table(["case", "LOD", "ms / frame", "real-time factor", "× vs", "LOD share",
                 "forces + assembly", "solves", "self-collision", "solves / frame",
                 "steps / frame", "triangles (mean)", "solver"], body)
    return md + [""]


def _solvers_section(result: dict, out: str) -> list[str]:
    rows = result["rows"]
    cases = list(dict.fromkeys(r["case"] for r in rows))
    backends = list(dict.fromkeys(r["backend"] for r in rows if r["backend"] != "auto"))
    by = {(r["case"], r["backend"]): r for r in rows}
    md = ["## Linear-solver backends: `cloth-lod bench --solvers`", "",
          f"Command: {_suite_command(result, '--solvers', out)}  ",
          machine_line(result["machine"]) + "  ",
          f"{result['repeats']} repeats per run in rounds, {result.get('minutes', 0):.1f} min "
          "in all.", "",
          "Every backend runs the same steps of each case in a fresh process pinned to one CPU "
          "with one thread; ms per step is the median of the repeats, and ratios are to `pcg` "
          "on the same case in the same session. `auto` names the backend it ran. A blank "
          "cell: the backend was not run on that case.", ""]
    body = []
    for case in cases:
        pcg = by.get((case, "pcg"))
        cells = [case] + [
            (f"{by[(case, b)]['ms_per_step']:.1f}"
             + (f" ({by[(case, b)]['cg_iterations_per_step']:.0f} CG it.)" if b == "pcg" else ""))
            if (case, b) in by else "" for b in backends]
        auto = by.get((case, "auto"))
        cells += ([f"{auto['ms_per_step']:.1f} ({auto['solver']})",
                   f"{auto['ratio_to_pcg']:.2f}" if pcg and auto.get("ratio_to_pcg") else ""]
                  if auto else ["", ""])
        body.append(cells)
    md += table(["case (ms / step)"] + backends + ["auto", "auto × pcg"], body)
    md += ["", "Every run, with the solve's share of the step and the largest distance of the "
           "final cloth from the `pcg` run of the same case:", ""]
    md += table(["case", "backend (ran)", "ms / step", "× pcg", "solve share", "CG it. / step",
                 "solves / step", "max distance from pcg"],
                [[r["case"], f"{r['backend']} ({r['solver']})", f"{r['ms_per_step']:.1f}",
                  "" if r.get("ratio_to_pcg") is None else f"{r['ratio_to_pcg']:.2f}",
                  pct(r["solve_share"]), f"{r['cg_iterations_per_step']:.0f}",
                  f"{r['solves_per_step']:.1f}",
                  "" if r.get("max_distance_from_pcg_m") is None
                  else f"{1e3 * r['max_distance_from_pcg_m']:.3f} mm"] for r in rows])
    return md + [""]


def _contact_section(result: dict, out: str) -> list[str]:
    return ["## Contact scenes against their converged motion: `cloth-lod bench --contact`", "",
            f"Command: {_suite_command(result, '--contact', out)}  ",
            machine_line(result["machine"]) + "  ",
            f"{result.get('minutes', 0):.1f} min in all (cached references count as no time).",
            "", contact_table(result).rstrip("\n"), ""]


def _contact_pct(x) -> str:
    return "—" if x is None else (f"{100 * x:.2g} %" if x < 0.1 else f"{100 * x:.1f} %")


def contact_table(result: dict) -> str:
    """The table of ``cloth-lod bench --contact`` (:mod:`.contact`): its ``contact.md``
    and this page's section."""
    rows = result["rows"]
    times = rows[0]["times"] if rows else []
    lines = [f"Contact scenes at their default settings against the converged motion of the "
             f"same model (uniform mesh at the scene's level, `sdirk2` at a fixed h_ref = "
             f"H/{result.get('divisor', 8)}), {result['repeats']} timed repeats each, one "
             f"pinned thread ({result['machine']['platform']}). Error: RMS distance over a "
             "21 × 21 grid of material points as a fraction of the 1 m side (largest in "
             "brackets). The reference's own error: the whole difference between it and the "
             "same run at 2 h_ref (a bound for any order of convergence ≥ 1; the second-order "
             "estimate is a third of it). Sensitivity floor: the reference against itself "
             "with every start position moved by 1 nm, at each sample time (folds over a "
             "ball or on a floor pick their direction from whatever breaks the symmetry "
             "first; an error below this cannot be told from it). Cost: CPU seconds per "
             "simulated second of the default run, median (min–max).", "",
             "| scene | level | " + " | ".join(f"error at {t:g} s" for t in times)
             + " | reference's own error | sensitivity floor | CPU s / sim s | steps / frame "
             "| solves / frame |",
             "|---|---|" + "---|" * len(times) + "---|---|---|---|---|"]
    for r in rows:
        floor = r.get("sensitivity_rms_frac")
        floor = (" / ".join(_contact_pct(e) for e in floor) if floor else "not measured")
        lines.append(
            f"| {r['scene']} | {r['level']} | "
            + " | ".join(f"{_contact_pct(e)} ({_contact_pct(m)})"
                         for e, m in zip(r["rms_frac"], r["max_frac"]))
            + f" | ≤ {_contact_pct(max(r['reference_diff_rms_frac']))} | {floor} | "
            f"{r['cpu_per_sim_s_median']:.3g} ({r['cpu_per_sim_s_min']:.3g}–"
            f"{r['cpu_per_sim_s_max']:.3g}) | {r['substeps_per_frame']:.2f} | "
            f"{r['solves_per_frame']:.1f} |")
    if rows:
        low, high = min(r["load"][0] for r in rows), max(r["load"][1] for r in rows)
        lines += ["", f"1-minute load average during the timed runs: {low:.1f}–{high:.1f}."]
    return "\n".join(lines) + "\n"


def _local_section(result: dict, link: str) -> list[str]:
    """``--local``: the table per scene (as ``local.md``, which the file records)
    and its plots."""
    scenes = list(dict.fromkeys(r["scene"] for r in result["rows"]))
    md = ["## Where detail is local: `cloth-lod bench --local`", "",
          f"Command: {_suite_command(result, '--local', link)}  ",
          machine_line(result["machine"]), "", result.get("table", NOT_RECORDED)]
    md += [f"![{name}: error against cost]({link}/local_{name}.png)" for name in scenes]
    return md + [""]


def anchor(heading: str) -> str:
    """The fragment a Markdown renderer (GitHub's rule) gives a heading:
    lower case, punctuation other than ``-`` and ``_`` dropped, spaces to ``-``."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def markdown(results: dict[str, dict], results_link: str, command: str,
             out_dir: str | None = None) -> str:
    """The report page for ``results`` (from :func:`collect`).

    ``results_link``: the directory of the result files as the page links it
    (relative to the page, POSIX separators); ``command``: the command that
    writes the page, quoted at its top; ``out_dir``: that directory as the
    benchmark's ``--out`` names it (default ``results_link``).
    """
    out_dir = out_dir or results_link
    sections = {"bench": (_bench_section, f"{results_link}/bench.png"),
                "scenes": (_scenes_section, out_dir), "solvers": (_solvers_section, out_dir),
                "contact": (_contact_section, out_dir),
                "local": (_local_section, results_link)}
    parts = {key: render(results[key], arg) for key, (render, arg) in sections.items()
             if key in results}
    md = ["# Performance", "",
          f"<!-- Generated by `{command}`: edit the generator "
          "(cloth_lod_ros/tools/bench/performance.py), not this page. -->", "",
          f"This page is written by `{command}` from the benchmark's output files in "
          f"[`{out_dir}`]({results_link}/). Each section names the command that produced "
          "its numbers and the machine it ran on. Timings depend on the machine and on what "
          "else runs on it: ratios within one table come from one session (runs in rounds), "
          "ratios across tables do not.", ""]
    for lines in parts.values():             # a contents line per section
        title = lines[0].lstrip("# ")
        md.append(f"- [{title.split(':')[0]}](#{anchor(title)})")
    md.append("")
    for lines in parts.values():
        md += lines
    return "\n".join(md).rstrip("\n") + "\n"


def write_report(path: Path, results_dir: Path) -> str:
    """Write the report of the results in ``results_dir`` to ``path``; return
    the page.  Raises ``FileNotFoundError``/``ValueError`` as :func:`collect`."""
    path, results_dir = Path(path), Path(results_dir)
    results = collect(results_dir)
    link = Path(os.path.relpath(results_dir.resolve(), path.resolve().parent)).as_posix()
    command = f"cloth-lod bench --report {path.as_posix()} --out {results_dir.as_posix()}"
    page = markdown(results, link, command, results_dir.as_posix())
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page)
    return page
