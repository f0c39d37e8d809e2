"""The sweep's speed-up, measured: ``python -m cloth_lod_ros.tools.sweep.speed SPEC``.

A benchmark, not a test (issue 35's target: on the local default the sweep
takes at most 0.6x the time of its runs one after another).  Each round runs,
alternated so that both see the same machine:

* **serial**: a fresh Python process that plans the sweep and runs its tasks
  (:func:`~cloth_lod_ros.tools.sweep.task.run_one`, the same task the workers
  run) one after another, every thread pool at one thread;
* **sweep**: ``cloth-lod sweep SPEC --out TMP --quiet`` (a fresh process: the
  local cluster's start, the workers' imports and kernel loads, the runs and
  the table are all on the clock).

Both clocks are the wall time of the whole process, from start to exit.  It
prints each round's times, their ratio and the load average; the CPU
seconds of each process tree and, from the tables, those inside
``sim.step()``; and the overhead per run: ``(workers x sweep wall - serial
wall) / runs`` (worker time the sweep spends beyond the serial work) and the
extra CPU seconds per run.  On a shared machine with per-session CPU
scheduling (Linux autogroup: every process of one login session shares one
session's share), the workers get no more CPU than one process when other
sessions are busy: run it on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time as _time
from pathlib import Path

__all__ = ["main"]

_THREADS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
            "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS", "NUMBA_NUM_THREADS")


def _serial(spec_path: str, out: str) -> None:
    """In a fresh process: every run of the sweep in turn; their results as JSON."""
    from .command import _task
    from .spec import load_spec, plan_runs
    from .task import run_one
    spec = load_spec(spec_path)
    rows = []
    for p in plan_runs(spec):
        if p.scene is None:
            continue
        r = run_one(_task(spec, p))
        rows.append({k: r.get(k) for k in ("run_id", "status", "cpu_s", "wall_s", "setup_s")})
    Path(out).write_text(json.dumps(rows))


def _env() -> dict:
    env = dict(os.environ, **{name: "1" for name in _THREADS})
    root = str(Path(__file__).resolve().parents[3])
    env["PYTHONPATH"] = os.pathsep.join([root] + [p for p in env.get("PYTHONPATH", "").split(
        os.pathsep) if p])
    return env


def _timed(cmd: list[str]) -> tuple[float, float]:
    """Wall seconds of ``cmd`` and the CPU seconds of it and its children (the
    cluster's worker processes are its children)."""
    import resource
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = _time.perf_counter()
    proc = subprocess.run(cmd, env=_env(), capture_output=True, text=True)
    wall = _time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return wall, (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)


def _table_steps(out: Path) -> tuple[float, float, int]:
    """CPU and wall seconds in sim.step() summed over the sweep's table, and its runs."""
    from .table import read_rows, table_path
    ok = [r for r in read_rows(table_path(out, "auto")) if r["status"] == "ok"]
    return (sum(float(r["cpu_s"]) for r in ok), sum(float(r["wall_s"]) for r in ok), len(ok))


_PAIRED_RUNS = [(k, b) for k in (500.0, 1000.0, 2000.0, 4000.0) for b in (5.0e-5, 4.0e-4)]


def _one_run(k: float, b: float, duration: float = 2.0) -> tuple[float, float]:
    """One ``hang_two_corners`` run (stretch ``k`` N/m, bend ``b`` N m): the CPU
    seconds of this thread and the wall seconds inside ``sim.step()``."""
    from ...sim import ClothSim, load_scene
    sim = ClothSim(load_scene("hang_two_corners", [f"material.stretch_stiffness={k!r}",
                                                   f"material.bend_stiffness={b!r}"]))
    cpu = wall = 0.0
    while sim.time < duration - 1e-9:
        c0, w0 = _time.thread_time(), _time.perf_counter()
        sim.step()
        cpu += _time.thread_time() - c0
        wall += _time.perf_counter() - w0
    return cpu, wall


def _serve(threaded: bool) -> None:
    """A plain process for --paired: one run per line of stdin (``[k, b]``), in
    the main thread or in a second thread; its times as a JSON line."""
    import threading
    for line in sys.stdin:
        k, b = json.loads(line)
        if threaded:
            box = []
            t = threading.Thread(target=lambda: box.append(_one_run(k, b)))
            t.start()
            t.join()
            result = box[0]
        else:
            result = _one_run(k, b)
        print(json.dumps(result), flush=True)


def paired(rounds: int) -> None:
    """The same runs alternated run by run between a plain process's main thread,
    a plain process's second thread and a one-worker local cluster's task thread
    (all three kept alive, kernels loaded first); prints each run's CPU seconds
    and, per place, the median ratio to the main thread's."""
    import statistics
    from .cluster import close, open_client
    client, cluster = open_client(None, 1)
    procs = {}
    try:
        for place in ("main", "thread"):
            procs[place] = subprocess.Popen(
                [sys.executable, "-c", "import sys; from cloth_lod_ros.tools.sweep.speed import "
                 f"_serve; _serve({place == 'thread'})"], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, text=True, env=_env())

        def call(place, k, b):
            if place == "worker":
                return client.submit(_one_run, k, b, pure=False).result()
            procs[place].stdin.write(json.dumps([k, b]) + "\n")
            procs[place].stdin.flush()
            return json.loads(procs[place].stdout.readline())

        order = ["main", "thread", "worker"]
        for place in order:                      # imports and kernels, not timed
            call(place, 1000.0, 1.0e-4)
        cpu = {place: [] for place in order}
        for i, (k, b) in enumerate(_PAIRED_RUNS * rounds):
            for place in (order if i % 2 == 0 else order[::-1]):
                cpu[place].append(call(place, k, b)[0])
            print(f"run {i + 1}: " + ", ".join(f"{p} {cpu[p][-1]:.3f}" for p in order)
                  + f" CPU s (load {os.getloadavg()[0]:.1f})", flush=True)
        for place in ("thread", "worker"):
            r = [a / m for a, m in zip(cpu[place], cpu["main"])]
            print(f"{place} / main thread, CPU s per run: median {statistics.median(r):.3f} "
                  f"(min {min(r):.2f}, max {max(r):.2f}, {len(r)} runs)")
    finally:
        for proc in procs.values():
            proc.stdin.close()
            proc.wait()
        close(client, cluster)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m cloth_lod_ros.tools.sweep.speed",
        description="Time a sweep on the local default against its runs one after another.")
    parser.add_argument("spec", nargs="?", default=str(
        Path(__file__).resolve().parents[3] / "config" / "sweeps" / "speed16.yaml"),
                        help="sweep file (default config/sweeps/speed16.yaml: 16 two-second "
                             "hang_two_corners variants)")
    parser.add_argument("--rounds", type=int, default=1, help="alternated rounds (default 1)")
    parser.add_argument("--workers", type=int, help="the sweep's --workers (default: its own)")
    parser.add_argument("--paired", type=int, metavar="ROUNDS",
                        help="instead: the CPU time of the same runs in a worker, a plain "
                             "process's main thread and a second thread, alternated run by "
                             "run (8 runs per round)")
    args = parser.parse_args(argv)
    if args.paired:
        paired(args.paired)
        return 0
    py = sys.executable
    n_workers = args.workers or len(os.sched_getaffinity(0))
    print(f"{args.spec}: serial (one process, runs in turn) vs cloth-lod sweep "
          f"({n_workers} workers), {args.rounds} round(s), {os.cpu_count()} CPUs", flush=True)
    ratios = []
    with tempfile.TemporaryDirectory(prefix="cloth_sweep_speed_") as tmp:
        for r in range(args.rounds):
            load0 = os.getloadavg()[0]
            serial_json = Path(tmp) / f"serial{r}.json"
            t_serial, cpu_serial = _timed([py, "-c", "import sys; from cloth_lod_ros.tools."
                                           "sweep.speed import _serial; _serial(sys.argv[1], "
                                           "sys.argv[2])", args.spec, str(serial_json)])
            rows = json.loads(serial_json.read_text())
            serial_cpu = sum(x["cpu_s"] for x in rows if x["status"] == "ok")
            out = Path(tmp) / f"sweep{r}"
            cmd = [py, "-m", "cloth_lod_ros.tools.cli", "sweep", args.spec, "--out", str(out),
                   "--quiet"] + (["--workers", str(args.workers)] if args.workers else [])
            t_sweep, cpu_sweep = _timed(cmd)
            sweep_cpu, sweep_wall, n = _table_steps(out)
            load1 = os.getloadavg()[0]
            ratio = t_sweep / t_serial
            ratios.append(ratio)
            print(f"round {r + 1}: serial {t_serial:.1f} s, sweep {t_sweep:.1f} s, ratio "
                  f"{ratio:.2f} (load {load0:.1f} -> {load1:.1f})\n"
                  f"  CPU s in all: serial {cpu_serial:.1f}, sweep {cpu_sweep:.1f}; in sim.step(): "
                  f"serial {serial_cpu:.1f} ({serial_cpu / max(len(rows), 1):.3f} per run), "
                  f"sweep {sweep_cpu:.1f} ({sweep_cpu / max(n, 1):.3f} per run)\n"
                  f"  overhead per run: {(n_workers * t_sweep - t_serial) / max(n, 1):.2f} s of "
                  f"worker time (workers x sweep wall - serial wall, per run), "
                  f"{(cpu_sweep - cpu_serial) / max(n, 1):.2f} CPU s", flush=True)
    if len(ratios) > 1:
        print(f"ratio sweep/serial: median {sorted(ratios)[len(ratios) // 2]:.2f} "
              f"over {len(ratios)} rounds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
