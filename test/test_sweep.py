"""``cloth-lod sweep`` on real Dask processes (no timing assertions).

A ``dask scheduler`` and two ``dask worker --nthreads 1`` are started here as
subprocesses on free localhost ports, and ``cloth-lod sweep`` runs as a
subprocess against them, as a user would.  Outside truths checked: the
runs are the ones the sweep file asks (ids from ``--dry-run``, parameters in
the rows and in the scene each row holds), a stiffer cloth stretches less
(max strain falls with ``material.stretch_stiffness``), the scene loader's
refusal and the simulator's refused step come back as the errors of their
rows, a rerun from a row repeats the run bit for bit (same code, one thread),
``--resume`` runs nothing already in the table (row count and the run
folders' modification times), a LocalCluster gives the same numbers as the
separate scheduler, and a worker killed with SIGKILL mid-sweep loses no run.
The table is read with the ``csv`` module (pandas where installed).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cloth_lod_ros.sim import load_scene
from cloth_lod_ros.sim.scene.config import scene_to_dict
from cloth_lod_ros.tools.sweep.spec import load_spec, plan_runs, resolve_scene

pytest.importorskip("distributed", reason="the cluster extra: pip install '.[cluster]'")

REPO = Path(__file__).resolve().parent.parent
H = 1 / 60
# 2 x 2 grid of stretch and bend stiffness, plus a density the scene loader
# refuses and a gravity whose first step the simulator refuses: 6 runs.
TINY = """\
scene: hang_two_corners
duration: 0.05
set: {cloth.level: 2, lod.enabled: false}
grid:
  material.stretch_stiffness: [200.0, 5000.0]
  material.bend_stiffness: [1.0e-4, 1.0e-3]
list:
  - {material.density: -1.0}
  - {simulation.gravity: [0.0, 0.0, -1.0e+12]}
keep: [state, statistics]
"""
STIFFNESS = (200.0, 5000.0)
BEND = (1.0e-4, 1.0e-3)
# Longer runs for the killed worker and Ctrl-C: 6 x 0.4 s at level 3.
LONG = """\
scene: hang_two_corners
duration: 0.4
set: {cloth.level: 3, lod.enabled: false}
grid:
  material.stretch_stiffness: [300.0, 600.0, 1000.0, 1500.0, 2000.0, 3000.0]
keep: [statistics]
"""


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in env.get(
        "PYTHONPATH", "").split(os.pathsep) if p])         # the code under test, everywhere
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = "1"
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask(*args) -> list[str]:
    exe = Path(sys.executable).with_name("dask")
    return [str(exe), *args] if exe.exists() else [
        sys.executable, "-m", f"distributed.cli.dask_{args[0]}", *args[1:]]


class Cluster:
    """A ``dask scheduler`` and ``dask worker`` subprocesses (no nanny: each
    worker is the process its Popen names, so a kill kills the worker)."""

    def __init__(self, workdir: Path, workers: int = 2, worker_env: dict | None = None):
        self.port = _free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.log = (workdir / "dask.log").open("w")
        self.scheduler = subprocess.Popen(
            _dask("scheduler", "--host", "127.0.0.1", "--port", str(self.port),
                  "--no-dashboard", "--dashboard-address", "127.0.0.1:0"),
            env=_env(), stdout=self.log, stderr=subprocess.STDOUT, cwd=workdir)
        self.workers = {}
        for _ in range(workers):
            port = _free_port()
            proc = subprocess.Popen(
                _dask("worker", self.address, "--nthreads", "1", "--no-nanny",
                      "--host", "127.0.0.1", "--worker-port", str(port), "--no-dashboard",
                      "--death-timeout", "60"),
                env=worker_env or _env(), stdout=self.log, stderr=subprocess.STDOUT,
                cwd=workdir)
            self.workers[f"tcp://127.0.0.1:{port}"] = proc

    def stop(self) -> None:
        for proc in [*self.workers.values(), self.scheduler]:
            if proc.poll() is None:
                proc.terminate()
        for proc in [*self.workers.values(), self.scheduler]:
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self.log.close()


def sweep(*args, cwd: Path, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cloth_lod_ros.tools.cli", "sweep", *args],
                          env=_env(), cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)


def read_table(path: Path) -> list[dict]:
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    try:
        import pandas as pd
    except ImportError:
        return rows
    frame = pd.read_csv(path)           # what a user does; same rows and ids
    assert list(frame["run_id"]) == [r["run_id"] for r in rows]
    return rows


def mtimes(out: Path) -> dict:
    return {p.relative_to(out).as_posix(): p.stat().st_mtime_ns
            for p in sorted((out / "runs").rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    c = Cluster(tmp_path_factory.mktemp("dask"))
    yield c
    c.stop()


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, cluster):
    work = tmp_path_factory.mktemp("sweep")
    spec = work / "tiny.yaml"
    spec.write_text(TINY)
    planned = sweep(str(spec), "--dry-run", cwd=work)
    assert planned.returncode == 0, planned.stderr
    ids = [line.split("\t")[0] for line in planned.stdout.splitlines()]
    done = sweep(str(spec), "--scheduler", cluster.address, "--workers", "2", "--out",
                 str(work / "out"), "--format", "csv", cwd=work)
    return dict(work=work, spec=spec, ids=ids, proc=done, out=work / "out",
                rows=read_table(work / "out" / "sweep.csv"))


def test_every_run_has_a_row_and_failures_have_their_error(tiny, cluster):
    proc, rows = tiny["proc"], tiny["rows"]
    assert proc.returncode == 3, proc.stderr            # 3: some runs failed
    assert len(tiny["ids"]) == 6
    assert sorted(r["run_id"] for r in rows) == sorted(tiny["ids"])
    by_status = {s: [r for r in rows if r["status"] == s] for s in ("ok", "failed")}
    assert len(by_status["ok"]) == 4 and len(by_status["failed"]) == 2
    refused = [r for r in rows if r["material.density"] == "-1.0"]
    assert len(refused) == 1 and refused[0]["status"] == "failed"
    assert refused[0]["error"].startswith("SceneError") and "material.density" in \
        refused[0]["error"]
    assert refused[0]["worker"] == ""                   # never sent to a worker
    step = [r for r in rows if r["simulation.gravity"]]
    assert len(step) == 1 and step[0]["status"] == "failed"
    assert step[0]["error"].startswith("SimulationError"), step[0]["error"]
    assert step[0]["steps"] == "0"                      # the first step was refused
    for r in by_status["ok"]:
        assert r["worker"] in cluster.workers           # ran on a worker started here
        assert int(r["steps"]) == round(0.05 / H)
        assert float(r["cost_cpu_per_sim_s"]) > 0
        assert (tiny["out"] / "runs" / r["run_id"] / "state.npz").is_file()
        assert (tiny["out"] / "runs" / r["run_id"] / "stats.csv").is_file()


def test_rows_hold_the_parameters_asked_and_the_sim_used_them(tiny):
    ok = [r for r in tiny["rows"] if r["status"] == "ok"]
    combos = {(float(r["material.stretch_stiffness"]), float(r["material.bend_stiffness"]))
              for r in ok}
    assert combos == {(k, b) for k in STIFFNESS for b in BEND}
    strain = {}
    for r in ok:
        scene = json.loads(r["scene_json"])
        assert scene["material"]["stretch_stiffness"] == float(r["material.stretch_stiffness"])
        assert scene["material"]["bend_stiffness"] == float(r["material.bend_stiffness"])
        assert scene["cloth"]["level"] == 2 and scene["lod"]["enabled"] is False
        strain[(scene["material"]["stretch_stiffness"], scene["material"]["bend_stiffness"])] \
            = float(r["max_strain"])
        # The per-frame statistics the run kept agree with its row.
        with (tiny["out"] / "runs" / r["run_id"] / "stats.csv").open() as fh:
            frames = list(csv.DictReader(fh))
        assert len(frames) == int(r["steps"])
        assert max(float(f["max_strain"]) for f in frames) == float(r["max_strain"])
    for b in BEND:          # a stiffer cloth hanging under the same load stretches less
        assert strain[(5000.0, b)] < strain[(200.0, b)]


def test_resume_runs_nothing_new(tiny):
    before = mtimes(tiny["out"])
    again = sweep(str(tiny["spec"]), "--resume", "--out", str(tiny["out"]), "--format", "csv",
                  cwd=tiny["work"])
    assert again.returncode == 0, again.stderr
    assert "0 to run" in again.stdout
    rows = read_table(tiny["out"] / "sweep.csv")
    assert [r["run_id"] for r in rows] == [r["run_id"] for r in tiny["rows"]]
    assert mtimes(tiny["out"]) == before


def test_a_row_reruns_bit_for_bit(tiny):
    row = next(r for r in tiny["rows"] if r["status"] == "ok")
    dest = tiny["work"] / "rerun"
    proc = sweep("--rerun", str(tiny["out"] / "sweep.csv"), row["run_id"][:8], "--out",
                 str(dest), cwd=tiny["work"])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    with np.load(tiny["out"] / "runs" / row["run_id"] / "state.npz") as a, \
            np.load(dest / row["run_id"] / "state.npz") as b:
        assert a["x"].shape == b["x"].shape
        assert a["x"].tobytes() == b["x"].tobytes()
        assert a["v"].tobytes() == b["v"].tobytes()
        assert float(a["time"]) == pytest.approx(0.05)


def test_local_cluster_default_gives_the_same_table(tiny):
    """No --scheduler: a LocalCluster (one worker per core).  Same runs, same
    outcomes and the same numbers bit for bit (apart from timings and where)."""
    out = tiny["work"] / "local"
    proc = sweep(str(tiny["spec"]), "--out", str(out), "--format", "csv", cwd=tiny["work"])
    assert proc.returncode == 3, proc.stderr
    local = {r["run_id"]: r for r in read_table(out / "sweep.csv")}
    assert set(local) == {r["run_id"] for r in tiny["rows"]}
    for r in tiny["rows"]:
        mine = local[r["run_id"]]
        for key in ("status", "steps", "solves", "max_strain", "total_energy_j",
                    "z_min_m", "scene_json"):
            assert mine[key] == r[key], key
        assert mine["error"].split(" (")[0] == r["error"].split(" (")[0]


def test_a_killed_worker_loses_no_run_and_ctrl_c_resumes(tmp_path, cluster):
    """The last test on the module's cluster: it kills one of its workers."""
    c = cluster
    spec = tmp_path / "long.yaml"
    spec.write_text(LONG)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cloth_lod_ros.tools.cli", "sweep", str(spec),
         "--scheduler", c.address, "--workers", "2", "--out", str(out), "--format", "csv",
         "--quiet"], env=_env(), cwd=tmp_path, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    table = out / "sweep.csv"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if table.exists() and len(read_table(table)) >= 1:
            break
        time.sleep(0.1)
    first = read_table(table)
    assert len(first) >= 1, proc.communicate()
    # The other worker is in the middle of a run: kill it.
    victim = next(a for a in c.workers if a != first[0]["worker"])
    os.kill(c.workers[victim].pid, signal.SIGKILL)
    killed_at = len(first)
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 0, stderr
    rows = read_table(table)
    assert len(rows) == 6 and all(r["status"] == "ok" for r in rows), rows
    assert len({r["run_id"] for r in rows}) == 6
    assert all(r["worker"] != victim for r in rows[killed_at + 1:])

    # Ctrl-C (SIGINT) after the first row, then --resume: only what is missing runs.
    out2 = tmp_path / "out2"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cloth_lod_ros.tools.cli", "sweep", str(spec),
         "--scheduler", c.address, "--out", str(out2), "--format", "csv", "--quiet"],
        env=_env(), cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    table2 = out2 / "sweep.csv"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if table2.exists() and len(read_table(table2)) >= 1:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    before = read_table(table2)
    if proc.returncode == 0:        # all 6 finished before the signal landed
        assert len(before) == 6
        return
    assert proc.returncode == 130, stderr
    assert "--resume" in stderr and 1 <= len(before) < 6
    kept = mtimes(out2)
    done = sweep(str(spec), "--scheduler", c.address, "--out", str(out2), "--format",
                 "csv", "--resume", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert f"{len(before)} already in" in done.stdout
    after = read_table(table2)
    assert len(after) == 6 and len({r["run_id"] for r in after}) == 6
    assert [r["run_id"] for r in after[:len(before)]] == [r["run_id"] for r in before]
    now = mtimes(out2)
    assert {k: now[k] for k in kept} == kept       # the recorded runs were not redone


def test_no_scheduler_or_a_worker_of_another_version_stops_before_running(tmp_path):
    spec = tmp_path / "tiny.yaml"
    spec.write_text(TINY)
    nobody = sweep(str(spec), "--scheduler", f"tcp://127.0.0.1:{_free_port()}", "--timeout",
                   "2", "--out", str(tmp_path / "a"), cwd=tmp_path)
    assert nobody.returncode == 2 and "no Dask scheduler" in nobody.stderr, nobody.stderr
    assert not (tmp_path / "a").exists()
    # A worker whose environment has cloth_lod_ros 9.9.9 installed (its metadata first).
    fake = tmp_path / "site"
    (fake / "cloth_lod_ros-9.9.9.dist-info").mkdir(parents=True)
    (fake / "cloth_lod_ros-9.9.9.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: cloth_lod_ros\nVersion: 9.9.9\n")
    env = _env()
    env["PYTHONPATH"] = os.pathsep.join([str(fake), env["PYTHONPATH"]])
    other = Cluster(tmp_path, workers=1, worker_env=env)
    try:
        proc = sweep(str(spec), "--scheduler", other.address, "--out", str(tmp_path / "b"),
                     cwd=tmp_path)
    finally:
        other.stop()
    assert proc.returncode == 2, proc.stderr
    assert "cloth_lod_ros 9.9.9" in proc.stderr and next(iter(other.workers)) in proc.stderr
    assert not (tmp_path / "b").exists()


# -- the sweep file (in-process, no cluster) ------------------------------------------

def test_indexed_key_is_the_cli_override_of_the_whole_list(tmp_path):
    """``grasps[right].waypoints`` changes that grasp only: the same scene as
    ``--set grasps=[...]`` with the whole list written out."""
    base = scene_to_dict(load_scene("grasp_lift"))
    path = [[0.0, 0.5, 0.5, 0.004], [0.3, 0.5, 0.5, 0.2]]
    mine = resolve_scene(base, {"grasps[right].waypoints": path,
                                "obstacles[0].friction": 0.7})
    grasps = json.loads(json.dumps(base["grasps"]))
    grasps[1]["waypoints"] = path
    obstacles = json.loads(json.dumps(base["obstacles"]))
    obstacles[0]["friction"] = 0.7
    cli = scene_to_dict(load_scene("grasp_lift", [f"grasps={json.dumps(grasps)}",
                                                  f"obstacles={json.dumps(obstacles)}"]))
    assert mine == cli
    assert mine["grasps"][0] == base["grasps"][0]


def test_random_draws_are_seeded_bounded_and_stable_when_extended(tmp_path):
    text = """\
scene: hang_two_corners
duration: 0.1
random:
  samples: {n}
  seed: 11
  parameters:
    material.density: {{uniform: [0.1, 0.3]}}
    material.bend_stiffness: {{log_uniform: [1.0e-5, 1.0e-3]}}
    pins[top_left].radius: {{choice: [0.05, 0.0625]}}
"""
    spec = tmp_path / "r.yaml"
    spec.write_text(text.format(n=40))
    runs = plan_runs(load_spec(spec))
    assert len(runs) == 40 and len({r.run_id for r in runs}) == 40
    density = np.array([r.params["material.density"] for r in runs])
    bend = np.array([r.params["material.bend_stiffness"] for r in runs])
    assert np.all((0.1 <= density) & (density < 0.3))
    assert np.all((1e-5 <= bend) & (bend <= 1e-3))
    # log-uniform: the decades 1e-5..1e-4 and 1e-4..1e-3 get draws alike (not 1:9).
    assert 8 <= np.sum(bend < 1e-4) <= 32
    assert {r.params["pins[top_left].radius"] for r in runs} == {0.05, 0.0625}
    assert all(r.scene["pins"][0]["radius"] == r.params["pins[top_left].radius"]
               for r in runs)
    again = plan_runs(load_spec(spec))
    assert [r.params for r in again] == [r.params for r in runs]
    spec.write_text(text.format(n=50))
    more = plan_runs(load_spec(spec))
    assert [r.run_id for r in more[:40]] == [r.run_id for r in runs]


def test_parquet_table_reads_back(tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    from cloth_lod_ros.tools.sweep.table import Table
    table = Table(tmp_path / "sweep.parquet", ["run_id", "status", "x", "path"], resume=False)
    table.add(dict(run_id="a", status="ok", x=1.5, path=[[0, 1], [2, 3]]))
    table.add(dict(run_id="b", status="failed", x=None))
    table.flush()
    got = pq.read_table(tmp_path / "sweep.parquet").to_pylist()
    assert got == [dict(run_id="a", status="ok", x=1.5, path="[[0, 1], [2, 3]]"),
                   dict(run_id="b", status="failed", x=None, path=None)]
