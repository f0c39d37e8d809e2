"""``cloth-lod sweep``: the command (see :mod:`cloth_lod_ros.tools.sweep`)."""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import json
import shutil
import signal
import sys
import threading
import time as _time
from pathlib import Path

import numpy as np

from ...sim import SceneError
from .spec import PlannedRun, SweepError, SweepSpec, load_spec, plan_runs, scene_yaml
from .table import Table, read_rows, table_path
from .task import SUMMARY_COLUMNS, package_version, run_one

__all__ = ["add_arguments", "run", "columns_of", "EXIT_FAILED_RUNS", "EXIT_INTERRUPTED"]

EXIT_FAILED_RUNS = 3
EXIT_INTERRUPTED = 130
HEAD_COLUMNS = ["run_id", "kind", "status", "error", "index", "repeat", "sample", "seed",
                "reference_id"]
REFERENCE_COLUMNS = ["ref_error_rms_m", "ref_error_max_m", "ref_error_final_rms_m",
                     "ref_error_rms_of_side"]
TAIL_COLUMNS = ["worker", "host", "pid", "started_utc", "finished_utc", "package_version",
                "scene_json"]


def columns_of(spec: SweepSpec) -> list[str]:
    """The table's columns for ``spec``, in order."""
    return (HEAD_COLUMNS + spec.parameter_keys + list(SUMMARY_COLUMNS)
            + (REFERENCE_COLUMNS if spec.reference else []) + TAIL_COLUMNS)


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    parser.add_argument("spec", nargs="?", help="sweep file (YAML; docs/sweeps.md)")
    parser.add_argument("--out", help="output folder (default out/sweeps/<sweep file name>); "
                                      "with --rerun, the run's folder")
    parser.add_argument("--workers", type=int,
                        help="LocalCluster worker processes, one thread each (default: one per "
                             "core); with --scheduler, wait for this many")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run on an existing Dask scheduler, e.g. tcp://HOST:8786")
    parser.add_argument("--resume", action="store_true",
                        help="continue the sweep in --out: skip the runs already in its table")
    parser.add_argument("--retry-failed", action="store_true",
                        help="with --resume, also run again the runs recorded as failed")
    parser.add_argument("--timeout", type=float, default=60.0,
                        help="s to wait for the scheduler and its workers (default 60)")
    parser.add_argument("--retries", type=int, default=2,
                        help="times Dask re-runs a run whose worker was lost (default 2)")
    parser.add_argument("--format", choices=("auto", "parquet", "csv"), default="auto",
                        help="table format (default: Parquet if pyarrow is installed, else CSV)")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the runs (id, parameters, refusals) and stop")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    parser.add_argument("--rerun", nargs=2, metavar=("TABLE", "RUN_ID"),
                        help="run one row of a sweep's table again, here, from the scene and "
                             "settings in the row, and compare with what it recorded")
    return parser


def run(args) -> int:
    """Run the sweep (or ``--rerun``); 0 all runs ok, 3 some failed, 130 interrupted,
    2 a bad sweep file, scene or cluster."""
    from .cluster import ClusterError
    try:
        if args.rerun:
            return _rerun(Path(args.rerun[0]), args.rerun[1], args.out)
        if not args.spec:
            raise SweepError("give a sweep file (or --rerun TABLE RUN_ID)")
        return _sweep(args)
    except (SweepError, ClusterError) as exc:
        print(f"cloth-lod sweep: {exc}", file=sys.stderr)
        return 2


@contextlib.contextmanager
def _ctrl_c_after():
    """Hold a Ctrl-C (SIGINT) that arrives inside the block until its end."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    hits = []
    previous = signal.signal(signal.SIGINT, lambda *_: hits.append(1))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if hits:
        raise KeyboardInterrupt


def _utc(seconds) -> str | None:
    if seconds is None:
        return None
    return _dt.datetime.fromtimestamp(seconds, _dt.timezone.utc).isoformat(
        timespec="milliseconds")


def _task(spec: SweepSpec, planned: PlannedRun) -> dict:
    return dict(run_id=planned.run_id, scene=planned.scene, error=planned.error,
                keep=list(spec.keep), frames=spec.frames, grid_points=spec.grid_points,
                bag_rate=spec.bag_rate, version=package_version())


def _row(planned: PlannedRun, result: dict | None, error: BaseException | None) -> dict:
    """A table row from a run's plan and its task's result (or the task's failure)."""
    row = dict(run_id=planned.run_id, kind=planned.kind, index=planned.index,
               repeat=planned.repeat, sample=planned.sample, seed=planned.seed,
               reference_id=planned.reference_id, package_version=package_version(),
               scene_json=(json.dumps(planned.scene, separators=(",", ":"))
                           if planned.scene is not None else None),
               **planned.params)
    if result is None:
        row.update(status="failed", error=f"{type(error).__name__}: {error}"
                   + (" (the run's worker was lost, or the task could not run there)"
                      if type(error).__name__ in ("KilledWorker", "CommClosedError") else ""))
        return row
    row.update({k: result.get(k) for k in SUMMARY_COLUMNS})
    row.update(status=result["status"], error=result["error"], worker=result["worker"],
               host=result["host"], pid=result["pid"], started_utc=_utc(result["started"]),
               finished_utc=_utc(result["finished"]))
    return row


def _write_folder(runs_dir: Path, planned: PlannedRun, row: dict, result: dict | None) -> None:
    """``runs/<id>/``: scene.yaml, result.json, samples.npz and the kept files,
    written beside and renamed into place (a rerun replaces it whole)."""
    final = runs_dir / planned.run_id
    tmp = runs_dir / f".{planned.run_id}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    if planned.scene is not None:
        (tmp / "scene.yaml").write_text(
            f"# cloth-lod sweep run {planned.run_id}: the resolved scene "
            f"(cloth-lod run THIS_FILE runs it)\n" + scene_yaml(planned.scene))
    extra = {}
    if result is not None:
        for name, data in result["files"].items():
            path = tmp / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        if result.get("samples") is not None:
            np.savez(tmp / "samples.npz", samples=result["samples"],
                     times=np.asarray(result["sample_times"]), points=result["points"])
        extra = dict(traceback=result.get("traceback"), sample_times=result["sample_times"],
                     files=sorted(result["files"]))
    (tmp / "result.json").write_text(json.dumps(dict(row, **extra), indent=1, default=str))
    if final.exists():
        old = runs_dir / f".{planned.run_id}.old"
        shutil.rmtree(old, ignore_errors=True)
        final.rename(old)
        tmp.rename(final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        tmp.rename(final)


def _samples_of(result: dict | None) -> dict | None:
    """``{samples (k, m, 3) m, times (k,) s, points (m, 2) m}`` of a task's result."""
    if result is None or result.get("samples") is None:
        return None
    return dict(samples=result["samples"], times=np.asarray(result["sample_times"]),
                points=result["points"])


def _load_samples(runs_dir: Path, run_id: str):
    path = runs_dir / run_id / "samples.npz"
    if not path.exists():
        return None
    with np.load(path) as data:
        return dict(samples=data["samples"], times=data["times"], points=data["points"])


def _reference_error(run: dict, ref: dict | None, side: float) -> dict:
    """RMS and largest distance (m) between the run's and its reference's
    sample grids at the times both have (reference.point_distances)."""
    from ..reference import point_distances
    if ref is None or run is None or run["samples"] is None or ref["samples"] is None:
        return {}
    if run["points"].shape != ref["points"].shape or not np.allclose(run["points"],
                                                                      ref["points"]):
        return {}
    pairs = [(i, j) for i, t in enumerate(run["times"]) for j, u in enumerate(ref["times"])
             if abs(t - u) <= 1e-9 * max(1.0, abs(t))]
    if not pairs:
        return {}
    d = np.array([point_distances(run["samples"][i], ref["samples"][j]) for i, j in pairs])
    rms = float(np.sqrt(np.mean(d ** 2)))
    return dict(ref_error_rms_m=rms, ref_error_max_m=float(d.max()),
                ref_error_final_rms_m=float(np.sqrt(np.mean(d[-1] ** 2))),
                ref_error_rms_of_side=rms / side)


def _sweep(args) -> int:
    from .cluster import Progress, Runner, check_workers, close, open_client
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    started = _time.perf_counter()
    try:
        spec = load_spec(args.spec)
        planned = plan_runs(spec)
    except SceneError as exc:
        raise SweepError(f"scene error: {exc}") from None
    out = Path(args.out) if args.out else Path("out") / "sweeps" / spec.path.stem
    path = table_path(out, args.format)
    if args.format != "auto" and path.suffix != f".{args.format}":
        raise SweepError(f"--format {args.format}: {out} already holds {path.name}")
    if args.dry_run:
        for p in planned:
            print(f"{p.run_id}\t{p.kind}\t{'refused: ' + p.error if p.error else 'ok'}\t"
                  + json.dumps(p.params))
        return 0
    if path.exists() and not args.resume:
        raise SweepError(f"{path} exists: --resume continues that sweep, or choose another "
                         "--out")
    previous = read_rows(path) if args.resume and path.exists() else []
    statuses = ("ok",) if args.retry_failed else ("ok", "failed")
    done = {r["run_id"] for r in previous if r.get("status") in statuses}
    todo = [p for p in planned if p.run_id not in done]
    to_submit = [p for p in todo if p.scene is not None]
    say(f"cloth-lod sweep: {len(planned)} runs ({sum(p.kind == 'reference' for p in planned)}"
        f" reference), {len(planned) - len(todo)} already in {path}, {len(todo)} to run")
    client = cluster = None
    if to_submit:       # the cluster first: nothing is written if it cannot run the sweep
        client, cluster = open_client(args.scheduler, args.workers, timeout=args.timeout)
        try:
            workers = check_workers(
                client, need_ros="bag" in spec.keep,
                say=lambda m: print(f"cloth-lod sweep: {m}", file=sys.stderr))
        except BaseException:
            close(client, cluster)
            raise
        say(f"  on {len(workers)} worker(s) at {client.scheduler.address}")
    try:
        table = Table(path, columns_of(spec), resume=args.resume)
    except BaseException:
        close(client, cluster)
        raise
    if args.retry_failed:
        table.drop(set(table.done(("failed",))))
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "sweep.yaml").exists():
        shutil.copyfile(spec.path, out / "sweep.yaml")
    runs_dir = out / "runs"
    by_id = {p.run_id: p for p in planned}
    side = {p.run_id: max(p.scene["cloth"]["width"], p.scene["cloth"]["height"])
            for p in planned if p.scene is not None}
    counts = dict(ok=0, failed=0)
    progress = Progress(len(todo), quiet=args.quiet)

    def record(p: PlannedRun, row: dict, result: dict | None, instant: bool = False) -> None:
        with _ctrl_c_after():               # a run's folder and row land whole, or not at all
            _write_folder(runs_dir, p, row, result)
            # A reference's own overrides are no parameter columns (its scene_json has them).
            table.add({k: v for k, v in row.items() if k in table.columns})
        failed = row["status"] != "ok"
        counts["failed" if failed else "ok"] += 1
        progress.update(done=1, failed=int(failed), instant=instant)

    runner = Runner(client, retries=max(args.retries, 0)) if client is not None else None
    interrupted = False
    try:
        # Refused parameters: recorded at once, never sent.
        for p in [p for p in todo if p.scene is None]:
            record(p, _row(p, dict(status="failed", error=p.error, worker=None, host=None,
                                   pid=None, started=None, finished=None, files={}), None),
                   None, instant=True)
        # References first: the runs' error columns wait for them.
        for p in sorted(to_submit, key=lambda p: p.kind != "reference"):
            runner.submit(run_one, _task(spec, p), p.run_id,
                          priority=10 if p.kind == "reference" else 0)
        references: dict[str, dict | None] = {}
        waiting: dict[str, list] = {}

        def reference_samples(ref_id):
            if ref_id not in references:
                if ref_id in runner.pending.values():
                    return "pending"
                references[ref_id] = _load_samples(runs_dir, ref_id)
            return references[ref_id]

        def finish_run(p: PlannedRun, row: dict, result: dict | None, ref) -> None:
            if ref is not None and result is not None:
                row.update(_reference_error(_samples_of(result), ref, side[p.run_id]))
            record(p, row, result)

        for run_id, result, error in (runner.results(tick=progress.update) if runner else ()):
            p = by_id[run_id]
            row = _row(p, result, error)
            if p.kind == "reference":
                references[run_id] = _samples_of(result)
                record(p, row, result)
                for q, q_row, q_result in waiting.pop(run_id, []):
                    finish_run(q, q_row, q_result, references[run_id])
                continue
            ref = reference_samples(p.reference_id) if p.reference_id else None
            if isinstance(ref, str):            # its reference has not finished yet
                waiting.setdefault(p.reference_id, []).append((p, row, result))
                continue
            finish_run(p, row, result, ref)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        cancelled = runner.cancel() if runner else 0
        table.flush()
        progress.close()
        close(client, cluster)
    wall = _time.perf_counter() - started
    if interrupted:
        print(f"cloth-lod sweep: interrupted: {counts['ok'] + counts['failed']} run(s) "
              f"recorded, {cancelled} cancelled; the table {path} is complete up to there: "
              f"continue with --resume", file=sys.stderr)
        return EXIT_INTERRUPTED
    say(f"cloth-lod sweep: {counts['ok']} ok, {counts['failed']} failed in {wall:.1f} s; "
        f"table {path}, runs in {runs_dir}")
    if counts["failed"]:
        say("  failed runs have their error in the table's 'error' column "
            "(--resume --retry-failed runs them again)")
    return EXIT_FAILED_RUNS if counts["failed"] else 0


def _rerun(table: Path, run_id: str, out: str | None) -> int:
    """Run one row again in this process from its ``scene_json`` and the sweep's
    settings (``sweep.yaml`` beside the table); compare with what it recorded."""
    import yaml
    rows = [r for r in read_rows(table) if str(r["run_id"]).startswith(run_id)]
    ids = sorted({r["run_id"] for r in rows})
    if len(ids) != 1:
        raise SweepError(f"{table}: {len(ids)} runs have an id starting {run_id!r}"
                         + (f": {', '.join(ids[:5])}" if ids else ""))
    row = rows[-1]
    if not row.get("scene_json"):
        raise SweepError(f"run {ids[0]} has no scene (its parameters were refused: "
                         f"{row.get('error')})")
    settings = {}
    spec_copy = table.parent / "sweep.yaml"
    if spec_copy.exists():
        settings = yaml.safe_load(spec_copy.read_text()) or {}
    keep = sorted(set(settings.get("keep", [])) - {"bag"} | {"state", "statistics"})
    planned = PlannedRun(ids[0], row["kind"], int(row["index"]), {},
                         scene=json.loads(row["scene_json"]))
    task = dict(run_id=ids[0], scene=planned.scene, keep=keep,
                frames=settings.get("frames", 10), grid_points=settings.get("grid_points", 11),
                bag_rate=30.0, version=None)
    result = run_one(task)
    new = _row(planned, result, None)
    dest = Path(out) if out else table.parent / "rerun"
    _write_folder(dest, planned, new, result)
    folder = dest / ids[0]
    print(f"rerun of {ids[0]}: status {new['status']}"
          + (f" ({new['error']})" if new["error"] else "") + f"; written to {folder}")
    same = True
    for key in ("steps", "max_strain", "total_energy_j", "solves"):
        recorded = row.get(key)
        if recorded in (None, ""):
            continue
        now = new.get(key)
        equal = now is not None and float(recorded) == float(now)
        same &= equal
        print(f"  {key:16s} recorded {recorded!s:>24s}  now {now!s:>24s}"
              f"  {'same' if equal else 'DIFFERENT'}")
    original = table.parent / "runs" / ids[0] / "state.npz"
    if original.exists():
        with np.load(original) as a, np.load(folder / "state.npz") as b:
            identical = (a["x"].shape == b["x"].shape and a["x"].tobytes() == b["x"].tobytes()
                         and a["v"].tobytes() == b["v"].tobytes())
        same &= identical
        print(f"  final state: {'identical bit for bit to' if identical else 'DIFFERS from'} "
              f"{original}")
    return 0 if same else 1
