"""The ``cloth-lod`` command line: run, outputs, error handling, scenes."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cloth_lod_ros.tools import cli
from cloth_lod_ros.sim.scene.config import load_scene
from cloth_lod_ros.sim import ClothSim, SimulationError, StepStats

REPO = Path(__file__).resolve().parent.parent
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# Uniform level 2 (the scene is adaptive by default): fixed shapes to check.
FAST = ["--level", "2", "--duration", "0.1", "--quiet", "--set", "lod.enabled=false"]
DURATION = 0.1


def run(tmp_path, *extra, out="state.npz"):
    return cli.main(["run", "hang_two_corners", *FAST, "--out", str(tmp_path / out), *extra])


@pytest.fixture(scope="module")
def fast_run(tmp_path_factory):
    """One fast run shared by the output checks."""
    tmp = tmp_path_factory.mktemp("run")
    code = run(tmp)
    with np.load(tmp / "state.npz") as data:
        arrays = {k: data[k] for k in data.files}
    return code, tmp, arrays


def test_run_exits_zero_and_writes_outputs(fast_run):
    code, tmp, _ = fast_run
    assert code == 0
    assert (tmp / "state.npz").stat().st_size > 0
    png = tmp / "state.png"                                   # default: beside --out
    assert png.stat().st_size > 1000
    assert png.read_bytes()[:8] == PNG_MAGIC


def test_state_file_keys_and_shapes(fast_run):
    _, _, d = fast_run
    scene = load_scene("hang_two_corners", ["cloth.level=2"])
    n = (4 * 2 + 1) ** 2                                      # level 2 of 4x4: 9x9 grid
    t = 32 * 4
    for key in ("x", "v", "uv", "mass", "triangles", "levels", "time", "pinned"):
        assert key in d, key
    assert d["x"].shape == (n, 3) and d["v"].shape == (n, 3)
    assert d["uv"].shape == (n, 2) and d["mass"].shape == (n,)
    assert d["triangles"].shape == (t, 3) and d["levels"].shape == (t,)
    assert np.issubdtype(d["triangles"].dtype, np.integer)
    assert d["triangles"].min() >= 0 and d["triangles"].max() < n
    assert np.all(d["levels"] == 2)
    assert np.all(np.isfinite(d["x"])) and np.all(np.isfinite(d["v"]))
    assert d["time"].shape == () and float(d["time"]) == pytest.approx(DURATION, abs=1e-9)
    assert d["mass"].sum() == pytest.approx(scene.material.density * 1.0 * 1.0, rel=1e-12)
    # Two pins at the top corners (v = 1 m).
    assert d["pinned"].shape == (2,)
    np.testing.assert_allclose(d["uv"][d["pinned"]], [[0.0, 1.0], [1.0, 1.0]], atol=1e-12)
    # The cloth has moved under gravity but the pins have not.
    start = np.asarray(scene.cloth.origin) + np.column_stack(
        [d["uv"], np.zeros(n)])
    np.testing.assert_allclose(d["x"][d["pinned"]], start[d["pinned"]], atol=1e-9)
    assert d["x"][:, 2].min() < start[:, 2].min() - 1e-3


def test_state_file_stats(fast_run):
    _, _, d = fast_run
    steps = int(round(DURATION / (1 / 60)))
    names = [f.name for f in dataclasses.fields(StepStats)]
    for name in names:
        assert d[f"stats_{name}"].shape[0] == steps, name
        if name != "triangles_per_level":
            assert d[f"stats_{name}"].ndim == 1, name
    np.testing.assert_array_equal(d["stats_triangles_per_level"].sum(axis=1),
                                  d["stats_triangle_count"])
    np.testing.assert_array_equal(d["stats_step_index"], np.arange(steps))
    assert np.all(np.diff(d["stats_time"]) > 0)
    assert d["stats_time"][-1] == pytest.approx(float(d["time"]))
    assert np.all(d["stats_vertex_count"] == len(d["x"]))
    assert np.all(d["stats_triangle_count"] == len(d["triangles"]))
    assert np.all(d["stats_pinned_count"] == 2)
    assert np.all(d["stats_kinetic_energy"] >= 0)
    stray = {k for k in d if k.startswith("stats_")} - {f"stats_{n}" for n in names}
    assert not stray


def test_no_png_writes_no_picture(tmp_path):
    assert run(tmp_path, "--no-png") == 0
    assert (tmp_path / "state.npz").is_file()
    assert not list(tmp_path.rglob("*.png"))


def test_png_path_in_new_directory(tmp_path):
    png = tmp_path / "pictures" / "deep" / "final.png"
    assert run(tmp_path, "--png", str(png), out="a/b/state.npz") == 0
    assert (tmp_path / "a" / "b" / "state.npz").is_file()
    assert png.read_bytes()[:8] == PNG_MAGIC


def test_default_output_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "hang_two_corners", *FAST, "--no-png"]) == 0
    assert (tmp_path / "out" / "hang_two_corners.npz").is_file()


def test_dt_and_set_overrides_reach_the_simulation(tmp_path):
    code = cli.main(["run", "hang_two_corners", "--level", "1", "--duration", "0.1",
                     "--dt", "0.025", "--set", "material.density=0.5", "--quiet",
                     "--set", "lod.enabled=false",
                     "--no-png", "--out", str(tmp_path / "s.npz")])
    assert code == 0
    with np.load(tmp_path / "s.npz") as d:
        assert len(d["stats_time"]) == 4
        np.testing.assert_allclose(d["stats_time"], [0.025, 0.05, 0.075, 0.1])
        assert d["mass"].sum() == pytest.approx(0.5, rel=1e-12)
        assert np.all(d["levels"] == 1)


def test_progress_and_summary_printed(tmp_path, capsys):
    code = cli.main(["run", "hang_two_corners", "--level", "1", "--duration", "0.1",
                     "--no-png", "--out", str(tmp_path / "s.npz")])
    assert code == 0
    out = capsys.readouterr().out
    assert "t =  0.100 s" in out                       # progress line of the last step
    assert "6 steps" in out and "wrote" in out


def test_quiet_suppresses_progress(tmp_path, capsys):
    assert run(tmp_path, "--no-png") == 0
    out = capsys.readouterr().out
    assert "CG" not in out.split("scene hang_two_corners")[0]
    assert "scene hang_two_corners" in out


@pytest.mark.parametrize("argv, field", [
    (["--set", "material.density=-1"], "material.density"),
    (["--set", "material.densty=1"], "material.densty"),
    (["--dt", "0"], "simulation.time_step"),
    (["--level", "-1"], "cloth.level"),
    (["--set", "cloth.base_blocks=[4, 2]"], "cloth.base_blocks"),
    (["--set", "nonsense"], "nonsense"),
])
def test_bad_override_exits_2_naming_field(tmp_path, capsys, argv, field):
    code = cli.main(["run", "hang_two_corners", "--level", "1", "--duration", "0.05",
                     "--out", str(tmp_path / "s.npz"), *argv])
    assert code == 2
    captured = capsys.readouterr()
    assert field in captured.err
    assert captured.err.startswith("cloth-lod:")
    assert "Traceback" not in captured.err + captured.out
    assert not (tmp_path / "s.npz").exists()              # refused before simulating


def test_unknown_scene_exits_2(tmp_path, capsys):
    code = cli.main(["run", "no_such_scene", "--out", str(tmp_path / "s.npz")])
    assert code == 2
    err = capsys.readouterr().err
    assert "no_such_scene" in err and "hang_two_corners" in err
    assert "Traceback" not in err


def test_missing_scene_file_exits_2(tmp_path, capsys):
    code = cli.main(["run", str(tmp_path / "missing.yaml")])
    assert code == 2
    assert "missing.yaml" in capsys.readouterr().err


def test_bad_scene_file_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("cloth: {width: 1.0, height: 1.0, base_blocks: [1, 1]}\n"
                   "simulation: {duration: 1.0}\n")
    assert cli.main(["run", str(bad)]) == 2
    assert "simulation.time_step" in capsys.readouterr().err


def test_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main([])
    assert info.value.code == 2
    with pytest.raises(SystemExit) as info:
        cli.main(["run", "hang_two_corners", "--level", "two"])
    assert info.value.code == 2
    assert "--level" in capsys.readouterr().err


def test_simulation_error_exits_3_and_saves_state(tmp_path, capsys, monkeypatch):
    real_step = ClothSim.step

    def failing_step(self):
        if len(self.stats) == 2:
            raise SimulationError("non-finite state (test)")
        return real_step(self)

    monkeypatch.setattr(ClothSim, "step", failing_step)
    code = run(tmp_path)
    assert code == 3
    assert "simulation stopped: non-finite state (test)" in capsys.readouterr().err
    with np.load(tmp_path / "state.npz") as d:
        assert d["stats_time"].shape == (2,)
        assert float(d["time"]) == pytest.approx(2 / 60)


def test_scenes_lists_builtin(capsys):
    assert cli.main(["scenes"]) == 0
    out = capsys.readouterr().out
    lines = out.strip().splitlines()
    assert any(line.split()[0] == "hang_two_corners" for line in lines)
    assert load_scene("hang_two_corners").description in out


def test_render_cloth_with_levels_and_pins(tmp_path):
    from cloth_lod_ros.tools.plotting import render_cloth
    from cloth_lod_ros.sim.mesh.mesh48 import base_mesh, refine_uniform
    mesh = refine_uniform(base_mesh(1.0, 1.0, 2, 2), 2)
    x = np.column_stack([mesh.uv, 0.1 * np.sin(3 * mesh.uv[:, 0])])
    levels = mesh.levels.copy()
    levels[::3] += 1                                          # more than one level
    path = tmp_path / "p.png"
    render_cloth(path, x, mesh.triangles, levels, np.array([0, 4]), title="t")
    assert path.read_bytes()[:8] == PNG_MAGIC
    flat = tmp_path / "flat.png"                              # degenerate extent
    render_cloth(flat, np.zeros((mesh.vertex_count, 3)), mesh.triangles)
    assert flat.read_bytes()[:8] == PNG_MAGIC


def test_console_script_subprocess(tmp_path):
    script = Path(sys.executable).parent / "cloth-lod"
    cmd = [str(script)] if script.exists() else [sys.executable, "-m", "cloth_lod_ros.tools.cli"]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    env["MPLBACKEND"] = "Agg"
    out = tmp_path / "sub.npz"
    proc = subprocess.run(cmd + ["run", "hang_two_corners", "--level", "1",
                                 "--duration", "0.05", "--out", str(out)],
                          cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "wrote" in proc.stdout
    with np.load(out) as d:
        assert float(d["time"]) == pytest.approx(0.05, abs=1e-9)
    assert out.with_suffix(".png").read_bytes()[:8] == PNG_MAGIC

    bad = subprocess.run(cmd + ["run", "hang_two_corners", "--set", "material.density=-1"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2
    assert "material.density" in bad.stderr and "Traceback" not in bad.stderr


def test_adaptive_run_writes_level_and_history_pictures(tmp_path, capsys):
    code = cli.main(["run", "hang_two_corners", "--level", "4", "--duration", "0.4",
                     "--quiet", "--out", str(tmp_path / "a.npz")])
    assert code == 0
    for name in ("a.png", "a_levels.png", "a_lod.png"):
        assert (tmp_path / name).read_bytes()[:8] == PNG_MAGIC
    out = capsys.readouterr().out
    assert "LOD (max level 4)" in out and "splits" in out
    with np.load(tmp_path / "a.npz") as d:
        assert d["levels"].max() <= 4
        assert d["stats_refines"].sum() > 0              # it adapted while swinging
        np.testing.assert_array_equal(d["stats_triangles_per_level"].sum(axis=1),
                                      d["stats_triangle_count"])


def test_compare_reports_speed_and_error(tmp_path, capsys):
    import json
    out = tmp_path / "cmp.json"
    code = cli.main(["compare", "hang_two_corners", "--level", "3", "--duration", "0.5",
                     "--grid", "6", "--json", str(out)])
    assert code == 0
    result = json.loads(out.read_text())
    assert result["uniform"]["lod_share"] == 0.0 and result["uniform"]["splits"] == 0
    assert result["adaptive"]["splits"] > 0
    assert result["uniform"]["max_triangles"] == 32 * 2**3
    assert result["adaptive"]["max_triangles"] <= 32 * 2**3
    h = result["time_step"]
    times = np.array([e["time"] for e in result["errors"]])
    np.testing.assert_allclose(times, [0.125, 0.25, 0.5], atol=h / 2 + 1e-12)  # on steps
    np.testing.assert_allclose(times / h, np.round(times / h), atol=1e-9)
    for key in ("errors", "uniform_errors", "same_step_errors"):
        for e in result[key]:
            assert 0.0 <= e["rms_m"] <= e["max_m"] < 0.1, key
            assert e["rms_fraction"] == pytest.approx(e["rms_m"])       # 1 m cloth
    assert result["speedup"] > 0
    assert "speed-up" in capsys.readouterr().out


def test_compare_measures_both_runs_against_the_converged_reference(tmp_path, capsys):
    """By default both runs are compared with the scene uniform at the level
    asked, sdirk2 at h/8 with 3 Newton iterations, and that reference's own
    error is estimated (2 h_ref; one level coarser with --mesh-check)."""
    import json
    out = tmp_path / "cmp.json"
    code = cli.main(["compare", "hang_two_corners", "--level", "2", "--duration", "0.25",
                     "--grid", "5", "--mesh-check", "--candidate-set",
                     "simulation.integrator=baraff_witkin", "--baseline-set",
                     "simulation.integrator=baraff_witkin", "--json", str(out)])
    assert code == 0
    text = capsys.readouterr().out
    assert "converged reference: uniform L2, sdirk2" in text
    assert "same-step reference (mesh error only)" in text     # the adaptive-uniform column
    result = json.loads(out.read_text())
    ref = result["reference"]
    assert ref["mode"] == "converged" and ref["level"] == 2 and ref["divisor"] == 8
    assert ref["time_step"] == pytest.approx(result["time_step"] / 8)
    assert ref["newton_iterations"] == 3
    assert ref["runs"]["reference"]["time_step"] == pytest.approx(result["time_step"] / 8)
    assert ref["runs"]["reference_2h"]["time_step"] == pytest.approx(result["time_step"] / 4)
    assert ref["runs"]["reference"]["integrator"] == "sdirk2"
    assert ref["runs"]["reference_coarse"]["max_triangles"] == 32 * 2       # level 1
    for own in ref["own_error"]:
        assert own["time_rms"] >= 0 and own["mesh_rms"] > 0
    # The uniform run at the reference's level and the paper's step: its
    # distance from the converged motion is time error, and it is not zero
    # (a same-step reference would give the uniform run distance 0).
    assert result["uniform"]["integrator"] == "baraff_witkin"
    assert all(e["rms_m"] > 0 for e in result["uniform_errors"])
    assert result["uniform_errors"][-1]["rms_m"] > 10 * ref["own_error"][-1]["time_rms"]


def test_compare_same_step_reference_is_labelled(tmp_path, capsys):
    import json
    out = tmp_path / "c.json"
    code = cli.main(["compare", "hang_two_corners", "--level", "3", "--duration", "0.25",
                     "--grid", "5", "--reference", "same-step", "--candidate-set",
                     "lod.enabled=false", "--candidate-set", "cloth.level=2", "--reference-set",
                     "solver.method=direct", "--json", str(out)])
    assert code == 0
    assert "same-step reference (mesh error only)" in capsys.readouterr().out
    result = json.loads(out.read_text())
    assert result["reference"] == dict(mode="same-step", label="same-step reference (mesh "
                                       "error only)", level=3, time_step=result["time_step"])
    assert result["uniform_errors"] is None and result["errors"] == result["same_step_errors"]
    assert result["adaptive"]["label"] == "candidate" and result["uniform"]["label"] == "reference"
    assert result["adaptive"]["max_triangles"] == 128 and result["uniform"]["max_triangles"] == 256
    assert result["uniform"]["cg_iterations_mean"] == 0.0          # LU reference
    assert all(e["rms_m"] > 0 for e in result["errors"])             # coarser mesh differs


@pytest.mark.parametrize("extra, message", [
    (["--reference-level", "2"], "coarser than the runs compared"),
    (["--reference-divisor", "0"], "divisor"),
    (["--grid", "1"], "at least 2"),
])
def test_compare_bad_arguments_exit_2(capsys, extra, message):
    code = cli.main(["compare", "hang_two_corners", "--level", "3", "--duration", "0.1"]
                    + extra)
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err


def test_compare_bad_reference_mode_exits_2(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["compare", "hang_two_corners", "--reference", "finest"])
    assert exc.value.code == 2


def test_zero_duration_writes_the_initial_state_and_its_pictures(tmp_path, capsys):
    """``run --duration 0`` used to crash in matplotlib after writing the npz."""
    out = tmp_path / "zero.npz"
    code = cli.main(["run", "hang_two_corners", "--duration", "0", "--frames", "3",
                     "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "no steps taken" in captured.out and "Traceback" not in captured.err
    initial = ClothSim(load_scene("hang_two_corners"))
    with np.load(out) as d:
        assert float(d["time"]) == 0.0
        np.testing.assert_array_equal(d["x"], initial.positions)
        np.testing.assert_array_equal(d["triangles"], initial.triangles)
        assert d["stats_time"].shape == (0,) and d["stats_step_ms"].dtype == np.float64
        assert d["stats_triangles_per_level"].shape == (0, initial.max_level + 1)
    for suffix in (".png", "_levels.png", "_lod.png"):
        assert out.with_name("zero" + suffix).read_bytes()[:8] == PNG_MAGIC, suffix


@pytest.mark.parametrize("argv", [["--duration", "-1"], ["--duration", "-0.5"],
                                  ["--dt", "-0.01"]])
def test_negative_duration_or_step_exits_2(tmp_path, capsys, argv):
    code = cli.main(["run", "hang_two_corners", "--out", str(tmp_path / "s.npz"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("cloth-lod: scene error:") and "Traceback" not in err
    assert "simulation.duration" in err or "simulation.time_step" in err
    assert not (tmp_path / "s.npz").exists()


def _limited_cli(args, cwd, memory_bytes=1 << 30):
    """``cloth-lod`` in a subprocess with at most ``memory_bytes`` of address space."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return subprocess.run([sys.executable, "-m", "cloth_lod_ros.tools.cli", *args], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=120,
                          preexec_fn=limit)


def test_hostile_scene_files_are_refused_in_bounded_memory(tmp_path):
    """A YAML alias bomb (9^9 strings once expanded) used to run for a minute and take
    gigabytes; 100 000-deep nesting and a 400-digit integer ended in tracebacks.
    Each must now be one line of error, exit 2, within 1 GB of address space.  So must
    the costly scenes of issue 34, which were within the per-field limits: a uniform
    level-12 mesh (38 s, 646 MB), 2^21 triangles with LOD off (still running after
    40 s), 50,000 waypoints (30 s) and 5,000 grasps (14.5 s)."""
    lines = ["name:", '  - &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"  - &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    rest = "cloth: {width: 1, height: 1, base_blocks: [4, 4]}\n" \
           "simulation: {time_step: 0.01, duration: 1}\n"
    cases = {
        "bomb.yaml": ("\n".join(lines) + "\n" + rest, "alias"),
        "deep.yaml": ("description: " + "[" * 100_000 + "]" * 100_000 + "\n" + rest, "nested"),
        "digits.yaml": (rest + "solver: {max_iterations: " + "9" * 400 + "}\n",
                        "'solver.max_iterations' is too large"),
        "blocks.yaml": (rest.replace("[4, 4]", "[4000, 4000]").replace("1, height: 1",
                                                                         "4000, height: 4000"),
                        "'cloth.base_blocks'"),
        "level12.yaml": (rest.replace("[4, 4]}", "[4, 4], level: 12}"),
                         "the limit is 32,768 triangles at the start"),
        "blocks32.yaml": (rest.replace("1, height: 1, base_blocks: [4, 4]}",
                                       "32, height: 32, base_blocks: [32, 32], level: 10}")
                          + "lod: {enabled: false}\n", "2,097,152 triangles"),
        "waypoints.yaml": (rest + "pins: [{uv: [0, 0], waypoints: ["
                           + ",".join(f"[{i}, 0, 0, 1]" for i in range(50_000)) + "]}]\n",
                           "more than 50,000 values"),
        "grasps.yaml": (rest + "grasps:\n" + "".join(
            f"  - {{name: g{i}, uv: [{i % 100 / 100}, {i // 100 / 50}]}}\n" for i in range(5000)),
                        "'grasps' has 5,000 entries"),
    }
    for name, (text, expected) in cases.items():
        (tmp_path / name).write_text(text)
        proc = _limited_cli(["run", name, "--no-png", "--quiet"], tmp_path)
        # `run` reads its scene before the line on the compiled kernels
        # (test_startup.py) and before importing the simulator: the refusal is the
        # only line.
        err = proc.stderr
        assert proc.returncode == 2, (name, proc.stderr[-2000:])
        assert err.startswith("cloth-lod: scene error:"), (name, proc.stderr[-2000:])
        assert expected in err and len(err.splitlines()) == 1, proc.stderr
        assert len(err) < 400 and "lol" not in err
