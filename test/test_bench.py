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
# Tiny: levels 0-2 of the 4 x 4 base, 0.1 s timed, rest capped at 0.2 s,
# two repeats (so the repeat logic runs), a 5 x 5 sample grid.
TINY = ["hang_two_corners", "--quick", "--levels", "0", "1", "2", "--max-levels", "2",
        "--thresholds", str(NEVER), "0.001", "--repeats", "2", "--duration", "0.1",
        "--rest-cap", "0.2", "--rest-window", "0.05", "--grid", "5", "--quiet"]


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
    for heading in ("## Set-up", "## What \"converged\" means", "## Results",
                    "## The paper's comparison on our code", "## Does adaptive beat uniform?"):
        assert heading in md, heading
    assert "cloth-lod bench hang_two_corners --quick" in md      # the command to reproduce


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
    assert set(rows) == {"uniform_L0", "uniform_L1", "uniform_L2", "uniform_L2_half_step",
                         f"adaptive_L2_{NEVER * 1e3:g}mm", "adaptive_L2_1mm"}
    assert rows["uniform_L2"]["kind"] == "reference"
    assert rows["uniform_L2_half_step"]["time_step_s"] == pytest.approx(1 / 120)
    machine = data["machine"]
    for key in ("cpu_model", "logical_cpus", "python", "numpy", "scipy", "date"):
        assert machine[key], key
    # Every worker ran pinned to the one CPU, with one repeat per round.
    for key, runs in data["runs"].items():
        assert len(runs) == (1 if key.endswith("half_step") else 2), key
        assert all(r["cpu"] == [machine["pinned_cpu"]] for r in runs), key
    rest = data["rest"]
    assert rest["time"] == pytest.approx(0.2) and rest["at_rest"] is False   # capped


def test_reference_against_itself_is_zero(tiny):
    _, _, data, _ = tiny
    ref = by_config(data["rows"])["uniform_L2"]
    for key in error_keys(ref):
        assert ref[key] == 0.0, key
    for row in data["rows"]:                   # same inputs, one thread: repeats agree
        assert row["repeat_max_deviation_m"] == 0.0, row["config"]


def test_rows_have_non_negative_errors_and_finite_costs(tiny):
    _, _, data, _ = tiny
    for row in data["rows"]:
        for key in error_keys(row):
            assert math.isfinite(row[key]) and row[key] >= 0.0, (row["config"], key)
        for key in ("wall_per_sim_s_median", "wall_per_sim_s_min", "wall_per_sim_s_max",
                    "cpu_per_sim_s_median", "ms_per_step_median"):
            assert math.isfinite(row[key]) and row[key] > 0.0, (row["config"], key)
        assert row["wall_per_sim_s_min"] <= row["wall_per_sim_s_median"] \
            <= row["wall_per_sim_s_max"]
        assert row["vertex_steps"] > 0 and row["cg_iterations"] >= 0
        assert row["solves_per_step"] >= 1 and row["solver"]
        assert 0.0 <= row["lod_share_median"] < 1.0
    rows = by_config(data["rows"])
    assert rows["uniform_L1"]["rms_frac_motion"] > 0.0      # a coarser mesh differs
    assert rows["adaptive_L2_1mm"]["lod_share_median"] > 0.0
    assert rows["uniform_L0"]["lod_share_median"] == 0.0


def test_adaptive_that_never_refines_has_the_base_level_error(tiny):
    _, _, data, _ = tiny
    rows = by_config(data["rows"])
    never, base = rows[f"adaptive_L2_{NEVER * 1e3:g}mm"], rows["uniform_L0"]
    assert never["splits"] == 0 and never["triangles_max"] == 32     # the 4 x 4 base
    for key in error_keys(never):
        assert never[key] == pytest.approx(base[key], rel=1e-9, abs=1e-12), key


@pytest.mark.parametrize("extra, message", [
    (["--levels", "-1", "2"], "below the base mesh"),
    (["--max-levels", "1", "--set", "lod.initial_level=2", "--levels", "2"],
     "below the level the adaptive run starts from"),
    (["--levels", "2", "4", "--reference-level", "3"], "finer than the reference level"),
    (["--thresholds", "0"], "positive"),
    (["--repeats", "0"], "at least 1"),
    (["--set", "cloth.width=-1"], "scene error"),
])
def test_bad_arguments_exit_2_with_a_message(tmp_path, capsys, extra, message):
    code = bench.main(["hang_two_corners", "--quick", "--out", str(tmp_path)] + extra)
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "bench.csv").exists()


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


def test_from_json_rewrites_the_same_tables(tiny, tmp_path):
    _, out, data, _ = tiny
    assert bench.main(["--from-json", str(out / "bench.json"), "--out", str(tmp_path)]) == 0
    assert (tmp_path / "bench.csv").read_text() == (out / "bench.csv").read_text()
    assert (tmp_path / "bench.md").read_text() == (out / "bench.md").read_text()
    assert json.loads((tmp_path / "bench.json").read_text()) == data
    assert (tmp_path / "bench.png").read_bytes()[:8] == PNG_MAGIC


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
