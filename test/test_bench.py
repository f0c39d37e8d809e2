"""``cloth-lod bench``: outputs, consistency and argument errors (no timing assertions)."""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cloth_lod_ros.tools import bench

REPO = Path(__file__).resolve().parent.parent
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
NEVER = 10.0        # m: a refine threshold no hanging 1 m cloth can reach
# Tiny: two families (the paper's step and sdirk2 under error control) on
# levels 0 and 2 of the 4 x 4 base and adaptive max level 2, 0.1 s timed, rest
# capped at 0.2 s, two repeats (so the repeat logic runs), a 5 x 5 sample
# grid; the converged reference is uniform L2 at h/8, with its runs at h/4
# and at L1.
TINY = ["hang_two_corners", "--quick", "--schemes", "baraff_witkin", "sdirk2@1e-3",
        "--levels", "0", "2", "--max-levels", "2", "--thresholds", str(NEVER), "0.001",
        "--repeats", "2", "--duration", "0.1", "--rest-cap", "0.2", "--rest-window", "0.05",
        "--grid", "5", "--quiet"]
H = 1 / 60
FAMILIES = ("baraff_witkin", "sdirk2_tol0.001")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    code = bench.main(TINY + ["--out", str(out)])
    data = json.loads((out / "bench.json").read_text())
    with (out / "bench.csv").open() as fh:
        table = list(csv.DictReader(fh))
    return code, out, data, table


def by_config(rows):
    return {r["config"]: r for r in rows}


def error_keys(row):
    """RMS and max distance columns: each sample time, at rest, during motion."""
    keys = [k for k in row if k.startswith(("rms_frac_", "max_frac_"))]
    assert len(keys) == 2 * (3 + 1 + 1)
    return keys


def test_quick_tiny_run_writes_all_four_files(tiny):
    code, out, _, _ = tiny
    assert code == 0
    for name in ("bench.csv", "bench.json", "bench.png", "bench.md"):
        assert (out / name).stat().st_size > 100, name
    assert (out / "bench.png").read_bytes()[:8] == PNG_MAGIC
    md = (out / "bench.md").read_text()
    for heading in ("## Set-up", "## The reference's own error", "## Results",
                    "## Speed against error", "## The paper's comparison on our code",
                    "## Does adaptive beat uniform?"):
        assert heading in md, heading
    assert "cloth-lod bench hang_two_corners --quick" in md      # the command to reproduce
    assert "--schemes baraff_witkin sdirk2@1e-3" in md
    assert "same-step" not in md


def test_converged_reference_is_the_default_and_reports_its_own_error(tiny):
    _, out, data, _ = tiny
    ref = data["reference"]
    assert ref["mode"] == "converged" and ref["integrator"] == "sdirk2"
    assert ref["level"] == 2 and ref["divisor"] == 8          # the finest level asked, h/8
    assert {r["reference"] for r in data["rows"]} == {"converged"}
    assert ref["time_step"] == pytest.approx(H / 8)
    assert ref["newton_iterations"] == 3 and ref["newton_tolerance"] == pytest.approx(1e-8)
    assert set(ref["runs"]) == {"reference", "reference_2h", "reference_coarse"}
    assert ref["runs"]["reference_coarse"]["level"] == 1
    # The workers really ran at h_ref and 2 h_ref, once each.
    runs = data["runs"]
    assert [r["time_step"] for r in runs["reference_L2"]] == [pytest.approx(H / 8)]
    assert [r["time_step"] for r in runs["reference_L2_2h"]] == [pytest.approx(H / 4)]
    assert [r["time_step"] for r in runs["reference_L1"]] == [pytest.approx(H / 8)]
    own = ref["own_error"]
    for tag in ("0.03333s", "0.05s", "0.1s", "motion"):
        assert own[tag]["time_rms"] >= 0 and math.isfinite(own[tag]["time_rms"]), tag
        assert own[tag]["time_max"] >= own[tag]["time_rms"]
        assert own[tag]["mesh_rms"] > 0, tag                   # L1 differs from L2
    assert own["rest"]["time_rms"] is None and own["rest"]["mesh_rms"] > 0
    md = (out / "bench.md").read_text()
    assert "Reference: the converged motion" in md
    assert "The converged reference's own error" in md
    assert md.count("The converged reference's own error") >= 3   # under every table
    # Every configuration is measured against it: even the uniform runs on the
    # reference's own mesh are not at distance 0 (another integrator and step).
    rows = by_config(data["rows"])
    for fam in FAMILIES:
        assert rows[f"{fam}_uniform_L2"]["rms_frac_motion"] > 0, fam
    # The paper's linearised step is farther from the converged motion than
    # sdirk2 under error control on the same mesh (time error, not mesh error).
    assert (rows["baraff_witkin_uniform_L2"]["rms_frac_motion"]
            > 5 * rows["sdirk2_tol0.001_uniform_L2"]["rms_frac_motion"])


def test_csv_and_json_rows_agree(tiny):
    _, _, data, table = tiny
    rows = data["rows"]
    assert [r["config"] for r in table] == [r["config"] for r in rows]
    for text_row, row in zip(table, rows):
        assert set(text_row) == set(row)
        for key, value in row.items():
            if value is None:
                assert text_row[key] == "", key
            elif isinstance(value, float):
                assert float(text_row[key]) == value, key       # written with repr()
            else:
                assert text_row[key] == str(value), key


def test_configurations_and_machine_recorded(tiny):
    _, _, data, _ = tiny
    rows = by_config(data["rows"])
    assert set(rows) == {f"{fam}_{mesh}" for fam in FAMILIES
                         for mesh in ("uniform_L0", "uniform_L2", f"adaptive_L2_{NEVER * 1e3:g}mm",
                                      "adaptive_L2_1mm")}
    assert {r["kind"] for r in rows.values()} == {"uniform", "adaptive"}
    assert rows["baraff_witkin_uniform_L2"]["integrator"] == "baraff_witkin"
    assert rows["sdirk2_tol0.001_adaptive_L2_1mm"]["error_tolerance_m"] == 0.001
    machine = data["machine"]
    for key in ("cpu_model", "logical_cpus", "python", "numpy", "scipy", "numba", "date"):
        assert machine[key], key
    # Every worker ran pinned to the one CPU; the reference runs once, the
    # configurations once per round.
    for key, runs in data["runs"].items():
        assert len(runs) == (1 if key.startswith("reference") else 2), key
        assert all(r["cpu"] == [machine["pinned_cpu"]] for r in runs), key
    rest = data["rest"]
    assert rest["time"] == pytest.approx(0.2) and rest["at_rest"] is False   # capped


def test_rows_have_non_negative_errors_and_finite_costs(tiny):
    _, _, data, _ = tiny
    for row in data["rows"]:
        for key in error_keys(row):
            assert math.isfinite(row[key]) and row[key] >= 0.0, (row["config"], key)
        for key in ("wall_per_sim_s_median", "wall_per_sim_s_min", "wall_per_sim_s_max",
                    "cpu_per_sim_s_median", "ms_per_frame_median"):
            assert math.isfinite(row[key]) and row[key] > 0.0, (row["config"], key)
        assert row["wall_per_sim_s_min"] <= row["wall_per_sim_s_median"] \
            <= row["wall_per_sim_s_max"]
        assert row["vertex_steps"] > 0 and row["cg_iterations"] >= 0
        assert row["substeps_per_frame"] >= 1 and row["rejected_steps"] >= 0
        assert row["solves_per_frame"] >= row["newton_iterations_per_frame"] >= 1
        assert row["solver"]
        assert 0.0 <= row["lod_share_median"] < 1.0
        assert row["repeat_max_deviation_m"] == 0.0, row["config"]   # one thread: repeats agree
    rows = by_config(data["rows"])
    assert rows["baraff_witkin_uniform_L0"]["rms_frac_motion"] > 0.0
    assert rows["baraff_witkin_adaptive_L2_1mm"]["lod_share_median"] > 0.0
    assert rows["baraff_witkin_uniform_L0"]["lod_share_median"] == 0.0
    # One linearised solve per frame for the paper's step; two stages for sdirk2.
    paper = rows["baraff_witkin_uniform_L2"]
    assert paper["substeps_per_frame"] == 1 and paper["solves_per_frame"] == 1
    assert rows["sdirk2_tol0.001_uniform_L2"]["newton_iterations_per_frame"] >= 2


def test_adaptive_that_never_refines_has_the_base_level_error(tiny):
    _, _, data, _ = tiny
    rows = by_config(data["rows"])
    for fam in FAMILIES:
        never, base = rows[f"{fam}_adaptive_L2_{NEVER * 1e3:g}mm"], rows[f"{fam}_uniform_L0"]
        assert never["splits"] == 0 and never["triangles_max"] == 32     # the 4 x 4 base
        for key in error_keys(never):
            assert never[key] == pytest.approx(base[key], rel=1e-9, abs=1e-12), (fam, key)


def test_same_step_reference_is_an_option_and_is_labelled(tmp_path):
    code = bench.main(["hang_two_corners", "--quick", "--reference", "same-step",
                       "--schemes", "baraff_witkin", "--levels", "0", "2", "--max-levels", "2",
                       "--repeats", "1", "--duration", "0.1", "--rest-cap", "0.2",
                       "--rest-window", "0.05", "--grid", "5", "--quiet", "--out", str(tmp_path)])
    assert code == 0
    data = json.loads((tmp_path / "bench.json").read_text())
    assert data["reference"]["mode"] == "same-step"
    assert data["reference"]["label"] == "same-step reference (mesh error only)"
    assert not any(key.startswith("reference") for key in data["runs"])   # no converged runs
    rows = by_config(data["rows"])
    ref = rows["baraff_witkin_uniform_L2"]
    assert ref["kind"] == "same_step"
    for key in error_keys(ref):
        assert ref[key] == 0.0, key                        # the reference against itself
    assert rows["baraff_witkin_uniform_L0"]["rms_frac_motion"] > 0
    assert {r["reference"] for r in data["rows"]} == {"same-step reference (mesh error only)"}
    with (tmp_path / "bench.csv").open() as fh:                    # the CSV says so too
        assert {r["reference"] for r in csv.DictReader(fh)} == {
            "same-step reference (mesh error only)"}
    md = (tmp_path / "bench.md").read_text()
    assert "same-step reference (mesh error only)" in md
    assert md.count("same-step reference (mesh error only)") >= 3    # set-up and every table
    assert "--reference same-step" in md
    assert "The reference's own error" not in md


def test_dry_run_lists_the_documented_plan(capsys):
    assert bench.main(["--quick", "--dry-run"]) == 0
    lines = [line.split("\t") for line in capsys.readouterr().out.strip().splitlines()]
    kinds = [line[1] for line in lines]
    assert kinds[:3] == ["reference", "reference_2h", "reference_coarse"]
    assert kinds.count("uniform") == 3 * 2 and kinds.count("adaptive") == 3
    assert {line[2] for line in lines[3:]} == {"2"}       # quick: two repeats
    assert "simulation.integrator=baraff_witkin" in lines[3][4]
    assert bench.main(["--dry-run"]) == 0                  # the full run: 5 families x 4
    lines = [line.split("\t") for line in capsys.readouterr().out.strip().splitlines()]
    assert len(lines) == 3 + 5 * 4
    assert "cloth.level=6" in lines[0][4] and "simulation.newton_iterations=3" in lines[0][4]


@pytest.mark.parametrize("extra, message", [
    (["--levels", "-1", "2"], "below the base mesh"),
    (["--max-levels", "1", "--set", "lod.initial_level=2", "--levels", "2"],
     "below the level the adaptive run starts from"),
    (["--levels", "2", "4", "--reference-level", "3"], "finer than the reference level"),
    (["--thresholds", "0"], "positive"),
    (["--repeats", "0"], "at least 1"),
    (["--schemes", "rk4"], "unknown integrator"),
    (["--schemes", "sdirk2@-1"], "must be >= 0"),
    (["--schemes", "sdirk2@fast"], "length in metres"),
    (["--schemes", "sdirk2", "sdirk2@0"], "given twice"),
    (["--reference-divisor", "0"], "at least 1"),
    (["--set", "cloth.width=-1"], "scene error"),
])
def test_bad_arguments_exit_2_with_a_message(tmp_path, capsys, extra, message):
    code = bench.main(["hang_two_corners", "--quick", "--out", str(tmp_path)] + extra)
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "bench.csv").exists()


def test_bad_reference_mode_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--reference", "finest", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_unknown_scene_from_the_command_line(tmp_path):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]))
    proc = subprocess.run([sys.executable, "-m", "cloth_lod_ros.tools.bench", "no_such_scene",
                           "--quick", "--out", str(tmp_path)],
                          capture_output=True, text=True, env=env, timeout=60)
    assert proc.returncode == 2
    assert "unknown scene 'no_such_scene'" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_add_arguments_and_run_are_the_module_api(tmp_path, capsys):
    import argparse
    parser = bench.add_arguments(argparse.ArgumentParser(prog="cloth-lod bench"))
    args = parser.parse_args(["no_such_scene", "--out", str(tmp_path)])
    assert args.scene == "no_such_scene" and args.out == str(tmp_path)
    assert bench.run(args) == 2
    assert "unknown scene" in capsys.readouterr().err
    defaults = parser.parse_args([])
    assert defaults.scene == "hang_two_corners" and not defaults.quick
    assert defaults.reference == "converged" and defaults.mesh_check


def test_from_json_rewrites_the_same_tables(tiny, tmp_path):
    _, out, data, _ = tiny
    assert bench.main(["--from-json", str(out / "bench.json"), "--out", str(tmp_path)]) == 0
    assert (tmp_path / "bench.csv").read_text() == (out / "bench.csv").read_text()
    assert (tmp_path / "bench.md").read_text() == (out / "bench.md").read_text()
    assert json.loads((tmp_path / "bench.json").read_text()) == data
    assert (tmp_path / "bench.png").read_bytes()[:8] == PNG_MAGIC


def test_from_json_refuses_a_file_that_is_not_a_bench_result(tmp_path, capsys):
    bad = tmp_path / "bench.json"
    bad.write_text(json.dumps({"rows": []}))
    assert bench.main(["--from-json", str(bad)]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_solver_comparison_runs_every_backend_on_the_same_steps(tmp_path):
    """``bench --solvers --quick``: every backend on each case, the same cloth
    within the solver tolerance, ratios to pcg from the same run."""
    assert bench.main(["--solvers", "--quick", "--repeats", "1", "--quiet",
                       "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "solvers.json").read_text())
    assert (tmp_path / "solvers.md").read_text().count("\n| ") == len(data["rows"]) + 1
    cases = {r["case"] for r in data["rows"]}
    assert len(cases) == 2
    for row in data["rows"]:
        assert row["unconverged_steps"] == 0
        assert row["solves_per_step"] >= 1
        assert row["max_distance_from_pcg_m"] < 1e-3, row
        assert row["ratio_to_pcg"] > 0
        if row["backend"] != "auto":
            assert row["solver"] == row["backend"]


def test_scene_table_times_every_case_and_pairs_self_collision_with_its_base(tmp_path):
    """``bench --scenes --quick``: one row per case with consistent shares; the
    self-collision case is compared with the same scene without it, and only
    it spends time on self-collision."""
    assert bench.main(["--scenes", "--quick", "--repeats", "1", "--quiet",
                       "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "scenes.json").read_text())
    # What the performance report quotes: the command and the machine.
    assert data["command"] == f"cloth-lod bench --scenes --quick --repeats 1 --out {tmp_path}"
    for key in ("cpu_model", "logical_cpus", "python", "numpy", "scipy", "numba", "date"):
        assert data["machine"][key], key
    from cloth_lod_ros.tools.bench.scenes import QUICK_SCENE_CASES
    assert [r["case"] for r in data["rows"]] == [c.label for c in QUICK_SCENE_CASES]
    assert (tmp_path / "scenes.md").read_text().count("\n| ") == len(data["rows"]) + 1
    for row, case in zip(data["rows"], QUICK_SCENE_CASES):
        assert row["unconverged_steps"] == 0
        assert row["solves_per_frame"] >= 1 and row["substeps_per_frame"] >= 1
        shares = [row[k] for k in ("lod_share", "force_share", "solve_share",
                                   "self_collision_share")]
        assert all(0.0 <= s <= 1.0 for s in shares) and sum(shares) <= 1.0 + 1e-9
        assert row["real_time_factor"] == pytest.approx(
            1e3 * row["frame_period_s"] / row["ms_per_frame"])
        if case.scene == "hang_two_corners":          # its scene file leaves it at auto: on
            enabled = "self_collision.enabled=false" not in case.overrides
            assert (row["self_collision_share"] > 0.0) == enabled
        if case.vs is None:
            assert row["ratio_to_vs"] is None
        else:
            base = next(r for r in data["rows"] if r["case"] == case.vs)
            assert row["ratio_to_vs"] == pytest.approx(row["ms_per_frame"]
                                                       / base["ms_per_frame"])


# --- the performance report (``--report``): one page from the output files -----------------

def _table_lines(page: str, first_cell: str) -> list[str]:
    """The table rows of ``page`` whose first cell is ``first_cell``."""
    return [line for line in page.splitlines() if line.startswith(f"| {first_cell} |")]


def _suite_costs(ms_per_frame: float, frames: int = 60, self_ms: float = 0.0) -> dict:
    """A worker's cost counters (``worker._worker``'s ``cost``) for a run of
    ``frames`` frames of 1/60 s taking ``ms_per_frame`` each."""
    internal = 0.9 * ms_per_frame * frames
    return dict(wall_s=ms_per_frame * frames / 1e3, steps=frames, simulated_s=frames / 60,
                internal_step_ms=internal, lod_ms=0.1 * internal, force_ms=0.2 * internal,
                assembly_ms=0.05 * internal, solve_ms=0.5 * internal,
                self_collision_ms=self_ms * frames, solves=2 * frames, substeps=frames,
                rejected_steps=0, unconverged_steps=0, triangles_mean=512.0,
                solvers=["block_ldl"])


@pytest.fixture(scope="module")
def report_inputs(tiny, tmp_path_factory):
    """A results directory as the three modes leave it: the tiny run's
    ``bench.json`` and plot, a ``scenes.json`` written by the suites' writer
    with rows from the scene table's row builder (command recorded), and a
    ``solvers.json`` as written before suites recorded their command and
    machine (the committed files' schema)."""
    import shutil
    import time
    from cloth_lod_ros.tools.bench import runner
    from cloth_lod_ros.tools.bench.scenes import SceneCase, _row, markdown as scenes_md
    _, out, _, _ = tiny
    results = tmp_path_factory.mktemp("results")
    for name in ("bench.json", "bench.png"):
        shutil.copy(out / name, results / name)
    base = SceneCase("hang L3", "hang_two_corners", ["cloth.level=3"], 1.0)
    other = SceneCase("hang L3, self-collision on", "hang_two_corners",
                      ["cloth.level=3", "self_collision.enabled=true"], 1.0, vs="hang L3")
    rows = [_row(base, [_suite_costs(t) for t in (4.0, 4.4, 5.0)]),
            _row(other, [_suite_costs(t, self_ms=0.2) for t in (4.6, 4.2, 6.0)])]
    rows[1].update(vs="hang L3", ratio_to_vs=rows[1]["ms_per_frame"] / rows[0]["ms_per_frame"])
    scenes = runner.write_suite(results, "scenes", rows, 3, 0, time.time(), scenes_md)
    scenes["command"] = f"cloth-lod bench --scenes --out {results}"
    (results / "scenes.json").write_text(json.dumps(scenes))
    solver_rows = [dict(case=case, backend=backend, solver=backend, ms_per_step=ms,
                        ratio_to_pcg=ms / pcg, solve_share=0.8, cg_iterations_per_step=cg,
                        solves_per_step=2.0, unconverged_steps=0, triangles_mean=512.0,
                        max_distance_from_pcg_m=d)
                   for case, pcg in (("uniform L3", 7.25), ("grasp_lift L3", 31.5))
                   for backend, ms, cg, d in (("pcg", pcg, 120.0, 0.0),
                                              ("block_ldl", pcg / 3, 0.0, 2.5e-5))]
    solvers = dict(machine=dict(platform="Linux-test-x86_64", processor="", cpu=1,
                                python="3.11.7"), repeats=2, minutes=1.5, rows=solver_rows)
    (results / "solvers.json").write_text(json.dumps(solvers))
    return results, json.loads((results / "bench.json").read_text()), scenes, solvers


def test_report_holds_every_row_with_its_machine_and_command(report_inputs, tmp_path):
    results, data, scenes, solvers = report_inputs
    page_path = tmp_path / "docs" / "performance.md"
    assert bench.main(["--report", str(page_path), "--out", str(results), "--quiet"]) == 0
    page = page_path.read_text()
    # The command that writes the page, and each section's own command.
    assert f"cloth-lod bench --report {page_path} --out {results}" in page
    assert f"Command: `{data['settings']['command']}`" in page
    assert f"Command: `{scenes['command']}`" in page
    assert f"`cloth-lod bench --solvers --repeats 2 --out {results}` (rebuilt" in page
    # The machine as each file records it; what a file lacks is said, not guessed.
    m = data["machine"]
    assert m["cpu_model"] and m["numba"]          # the bench records both now
    for value in (m["cpu_model"], f"logical CPUs: {m['logical_cpus']}", f"Python {m['python']}",
                  f"numpy {m['numpy']}", f"scipy {m['scipy']}", f"numba {m['numba']}",
                  m["date"]):
        assert value in page, value
    assert "CPU not recorded" in page and "numpy not recorded" in page   # the old solvers file
    assert "platform Linux-test-x86_64" in page
    if m.get("git_commit"):
        assert m["git_commit"].removesuffix("+dirty") not in page        # no commit hashes
    # Every row of every file, with its numbers.
    for r in data["rows"]:
        [line] = _table_lines(page, r["label"])
        assert f"| {r['wall_per_sim_s_median']:.3g} (" in line, r["label"]
        assert f"| {r['ms_per_frame_median']:.3g} |" in line, r["label"]
    for r in scenes["rows"]:
        [line] = _table_lines(page, r["case"])
        assert f"| {r['ms_per_frame']:.1f} | {r['real_time_factor']:.2f} |" in line, r["case"]
    assert f"{scenes['rows'][1]['ratio_to_vs']:.3f} × hang L3" in page
    for r in solvers["rows"]:
        lines = [line for line in _table_lines(page, r["case"])
                 if f"| {r['backend']} ({r['solver']}) |" in line]
        assert len(lines) == 1 and f"| {r['ms_per_step']:.1f} |" in lines[0], r
    # The pivot table: one line per case with each backend's time.
    for case, pcg in (("uniform L3", 7.25), ("grasp_lift L3", 31.5)):
        [line] = [line for line in _table_lines(page, case) if "CG it.)" in line]
        assert f"{pcg:.1f} (120 CG it.)" in line and f"| {pcg / 3:.1f} |" in line
    # The plot is linked relative to the page and resolves to the results' plot.
    import re
    [image] = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", page)
    assert (page_path.parent / image).resolve() == (results / "bench.png").resolve()
    # The contents lines point at the sections' headings.
    from cloth_lod_ros.tools.bench.performance import anchor
    headings = {anchor(line.lstrip("# ")) for line in page.splitlines()
                if line.startswith("## ")}
    targets = re.findall(r"^- \[[^\]]+\]\(#([^)]+)\)$", page, flags=re.M)
    assert len(targets) == 3 and set(targets) <= headings


def test_report_from_one_file_and_refusals(report_inputs, tmp_path, capsys):
    import shutil
    results, data, _, _ = report_inputs
    only = tmp_path / "only"
    only.mkdir()
    shutil.copy(results / "bench.json", only / "bench.json")
    page_path = tmp_path / "performance.md"
    assert bench.main(["--report", str(page_path), "--out", str(only), "--quiet"]) == 0
    page = page_path.read_text()
    assert "## Speed against error" in page
    assert "--scenes`" not in page and "--solvers`" not in page
    # An empty directory, or a file that is not a result: exit 2 with a message.
    empty = tmp_path / "empty"
    empty.mkdir()
    assert bench.main(["--report", str(tmp_path / "x.md"), "--out", str(empty)]) == 2
    assert "no benchmark results" in capsys.readouterr().err
    (only / "scenes.json").write_text(json.dumps({"rows": []}))
    assert bench.main(["--report", str(tmp_path / "x.md"), "--out", str(only)]) == 2
    assert "not a cloth-lod bench result" in capsys.readouterr().err
    assert not (tmp_path / "x.md").exists()


def test_committed_performance_page_is_the_report_of_the_committed_results():
    """docs/performance.md is generated: the report of the committed result
    files is the committed page, byte for byte (regenerate it with the
    command it quotes after changing the generator or the results)."""
    from cloth_lod_ros.tools.bench.performance import collect, markdown
    results = collect(REPO / "resource" / "readme" / "bench")
    assert set(results) == {"bench", "scenes", "solvers", "contact", "local"}
    page = markdown(results, "../resource/readme/bench",
                    "cloth-lod bench --report docs/performance.md --out resource/readme/bench",
                    "resource/readme/bench")
    assert page == (REPO / "docs" / "performance.md").read_text()
