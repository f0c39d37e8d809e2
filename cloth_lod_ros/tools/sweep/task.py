"""One sweep run, as it runs on a worker (``cloth-lod sweep``).

:func:`run_one` is the task the client submits: it builds the scene from the
resolved mapping it is given (no scene file needed on the worker), simulates
``simulation.duration`` seconds one frame at a time with every BLAS and
OpenMP pool at one thread, and returns the run's summary numbers, its samples
and the files it was asked to keep (as bytes: the client writes the run's
folder, so workers need no shared file system).  It never raises for a
failed run: a scene the loader refuses, a step the simulator refuses
(:class:`~cloth_lod_ros.sim.SimulationError`) or any other error comes back as
``status = "failed"`` with the error, and the numbers of the steps taken.
Only a lost worker makes the task itself fail (Dask then retries it).
"""

from __future__ import annotations

import csv
import io
import os
import socket
import tempfile
import time as _time
import traceback
from pathlib import Path

import numpy as np

__all__ = ["run_one", "package_identity", "package_version", "summary_columns", "SUMMARY_COLUMNS"]

#: Summary numbers of a run (the table's columns after the parameters), with units.
SUMMARY_COLUMNS = {
    "steps": "frames simulated (simulation.time_step each)",
    "simulated_s": "s",
    "wall_s": "s of wall time in sim.step()",
    "cpu_s": "s of CPU time (the task's thread) in sim.step()",
    "cost_cpu_per_sim_s": "CPU s per simulated s",
    "wall_per_sim_s": "wall s per simulated s",
    "setup_s": "s to build the simulator (scene, mesh, compiled-code warm-up)",
    "solves": "linear solves in all",
    "factorisations": "numeric factorisations in all",
    "cg_iterations": "CG iterations in all",
    "substeps": "integrator steps in all",
    "rejected_steps": "rejected step attempts in all",
    "newton_iterations": "Newton iterations in all",
    "unconverged_steps": "frames whose solve missed its tolerance",
    "max_strain": "largest stretch strain over the run",
    "max_speed_m_s": "largest particle speed over the run, m/s",
    "kinetic_energy_j": "final, J",
    "gravity_energy_j": "final, J (relative to z = 0)",
    "stretch_energy_j": "final, J",
    "shear_energy_j": "final, J",
    "bend_energy_j": "final, J",
    "total_energy_j": "final, J (the five above)",
    "triangles_mean": "active triangles, mean over frames",
    "triangles_final": "active triangles at the end",
    "vertices_final": "particles at the end",
    "splits": "LOD refinements in all",
    "merges": "LOD merges in all",
    "z_min_m": "lowest particle at the end, m",
    "z_mean_m": "mass-weighted mean height at the end, m",
    "projected_area_m2": "final triangles projected on the x-y plane, m^2 (overlaps count twice)",
}


def summary_columns() -> list[str]:
    return list(SUMMARY_COLUMNS)


def package_version() -> str:
    """The installed ``cloth_lod_ros`` version (``"source"`` without install metadata)."""
    from importlib import metadata
    try:
        return metadata.version("cloth_lod_ros")
    except metadata.PackageNotFoundError:
        return "source"


def package_identity() -> dict:
    """Which ``cloth_lod_ros`` this process imports: its version, a SHA-256 of
    its ``.py`` files (path and bytes) and where it is."""
    import hashlib
    import cloth_lod_ros
    root = Path(cloth_lod_ros.__file__).resolve().parent
    version = package_version()
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes())
    return dict(version=version, fingerprint=digest.hexdigest()[:16], path=str(root))


def _where() -> dict:
    try:
        from distributed import get_worker
        address = get_worker().address
    except (ImportError, ValueError):
        address = "local"
    return dict(worker=address, host=socket.gethostname(), pid=os.getpid())


def _stats_csv(stats) -> bytes:
    """Every frame's :class:`~cloth_lod_ros.sim.StepStats` as CSV (one row per frame;
    ``triangles_per_level`` as space-separated counts)."""
    from ...sim import StepStats
    names = list(StepStats.__dataclass_fields__)
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(names)
    for s in stats:
        writer.writerow([" ".join(str(int(c)) for c in v) if name == "triangles_per_level"
                         else repr(v) if isinstance(v, float) else v
                         for name in names for v in [getattr(s, name)]])
    return out.getvalue().encode()


def _summary(sim, cpu_s: float, wall_s: float, setup_s: float) -> dict:
    st = sim.stats
    h = sim.scene.simulation.time_step
    simulated = len(st) * h
    x, tri = sim.positions, sim.triangles
    cross_z = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])[:, 2]
    m = sim.masses
    out = dict(steps=len(st), simulated_s=simulated, wall_s=wall_s, cpu_s=cpu_s,
               cost_cpu_per_sim_s=cpu_s / simulated if simulated else None,
               wall_per_sim_s=wall_s / simulated if simulated else None, setup_s=setup_s,
               z_min_m=float(x[:, 2].min()), z_mean_m=float(m @ x[:, 2] / m.sum()),
               projected_area_m2=float(0.5 * np.abs(cross_z).sum()),
               vertices_final=int(len(x)), triangles_final=int(len(tri)))
    if not st:
        return out
    last = st[-1]
    out.update(
        solves=int(sum(s.solves for s in st)),
        factorisations=int(sum(s.factorisations for s in st)),
        cg_iterations=int(sum(s.cg_iterations for s in st)),
        substeps=int(sum(s.substeps for s in st)),
        rejected_steps=int(sum(s.rejected_steps for s in st)),
        newton_iterations=int(sum(s.newton_iterations for s in st)),
        unconverged_steps=int(sum(not s.converged for s in st)),
        max_strain=float(max(s.max_strain for s in st)),
        max_speed_m_s=float(max(s.max_speed for s in st)),
        kinetic_energy_j=last.kinetic_energy, gravity_energy_j=last.gravity_energy,
        stretch_energy_j=last.stretch_energy, shear_energy_j=last.shear_energy,
        bend_energy_j=last.bend_energy, total_energy_j=last.total_energy,
        triangles_mean=float(np.mean([s.triangle_count for s in st])),
        splits=int(sum(s.refines for s in st)), merges=int(sum(s.merges for s in st)))
    return out


def _read_tree(root: Path, prefix: str) -> dict:
    return {f"{prefix}/{p.relative_to(root).as_posix()}": p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


def run_one(task: dict) -> dict:
    """Simulate one run; return its row values, samples and kept files.

    ``task`` keys: ``run_id``, ``scene`` (resolved scene mapping, or None with
    ``error`` the reason), ``keep`` (subset of statistics, state, frames, bag),
    ``frames`` (sampled frames, the first at t = 0 and the last at the end),
    ``grid_points`` (material points per side of the sample grid),
    ``bag_rate`` (Hz of simulated time), ``version`` (the client's
    ``cloth_lod_ros`` version; a worker with another refuses the run).

    Returns a dict: ``status`` (``"ok"``/``"failed"``), ``error``, the
    :data:`SUMMARY_COLUMNS` (as far as the run got), ``worker``, ``host``,
    ``pid``, ``started``/``finished`` (Unix s), ``samples`` ((k, m, 3) m: the
    grid points at ``sample_times``, a quarter, half and all of the duration),
    ``sample_times`` (s), ``points`` ((m, 2) m) and ``files`` (relative path ->
    bytes).
    """
    from threadpoolctl import threadpool_limits
    out = dict(run_id=task["run_id"], status="ok", error=None, started=_time.time(),
               files={}, samples=None, sample_times=[], points=None, **_where())
    try:
        with threadpool_limits(limits=1), tempfile.TemporaryDirectory(
                prefix="cloth_sweep_") as tmp:
            _simulate(task, out, Path(tmp))
    except Exception as exc:                        # a failed run is data, not a crash
        out.update(status="failed", error=f"{type(exc).__name__}: {exc}",
                   traceback="".join(traceback.format_exc().splitlines(True)[-8:]))
    out["finished"] = _time.time()
    return out


def _simulate(task: dict, out: dict, tmp: Path) -> None:
    from ...sim import ClothSim, SimulationError
    from ...sim.scene.config import scene_from_dict
    from ...sim.mesh.sampling import material_grid
    if task.get("version") is not None and package_version() != task["version"]:
        raise RuntimeError(f"this worker imports cloth_lod_ros {package_version()}, the "
                           f"sweep was started with {task['version']}")
    if task.get("scene") is None:
        raise ValueError(task.get("error") or "no scene")
    keep = set(task.get("keep", ()))
    t0 = _time.perf_counter()
    scene = scene_from_dict(task["scene"])
    sim = ClothSim(scene)
    setup_s = _time.perf_counter() - t0
    h = scene.simulation.time_step
    steps = int(round(scene.simulation.duration / h))
    points = material_grid(scene.cloth.width, scene.cloth.height, int(task["grid_points"]))
    sample_steps = sorted({int(round(f * steps)) for f in (0.25, 0.5, 1.0)} - {0})
    frame_steps = (set(np.linspace(0, steps, int(task["frames"])).round().astype(int))
                   if "frames" in keep else set())
    frames: dict[str, list] = {"time": [], "grid_x": []}
    meshes: dict[str, np.ndarray] = {}

    def take_frame():
        i = len(frames["time"])
        frames["time"].append(sim.time)
        frames["grid_x"].append(sim.sample(points))
        meshes[f"x_{i}"], meshes[f"triangles_{i}"] = sim.positions.copy(), sim.triangles.copy()

    recording = None
    if "bag" in keep:
        from types import SimpleNamespace
        from ..cli import _HeadlessRecording        # the `cloth-lod run --bag` recorder
        args = SimpleNamespace(bag=str(tmp / "bag"), bag_compression="zstd",
                               bag_rate=float(task["bag_rate"]),
                               scene=f"cloth-lod sweep run {task['run_id']}")
        recording = _HeadlessRecording(args, sim, [], _time.perf_counter())
        record = recording.wrap(lambda s, stats: None)
    if 0 in frame_steps:
        take_frame()
    samples, times = [], []
    cpu_s = wall_s = 0.0
    failure = None
    try:
        for k in range(1, steps + 1):
            # Only sim.step() is on the clocks (the thread's CPU time: the task
            # runs in one worker thread with one BLAS thread).
            c0, w0 = _time.thread_time(), _time.perf_counter()
            try:
                stats = sim.step()
            finally:
                wall_s += _time.perf_counter() - w0
                cpu_s += _time.thread_time() - c0
            if recording is not None:
                record(sim, stats)
            if k in sample_steps:
                samples.append(sim.sample(points))
                times.append(sim.time)
            if k in frame_steps:
                take_frame()
    except SimulationError as exc:
        failure = exc                   # the numbers and files of the steps taken are kept
    finally:
        if recording is not None:
            recording.close()
    out.update(_summary(sim, cpu_s, wall_s, setup_s))
    out.update(samples=np.array(samples).reshape(len(samples), len(points), 3),
               sample_times=times, points=points)
    files = out["files"]
    if "statistics" in keep:
        files["stats.csv"] = _stats_csv(sim.stats)
    if "state" in keep:
        from ..cli import save_state
        save_state(tmp / "state.npz", sim)
        files["state.npz"] = (tmp / "state.npz").read_bytes()
    if "frames" in keep:
        buf = io.BytesIO()
        np.savez_compressed(buf, time=np.array(frames["time"]), grid_uv=points,
                            grid_x=np.array(frames["grid_x"]), **meshes)
        files["frames.npz"] = buf.getvalue()
    if recording is not None:
        if recording.recorder.failed:
            raise RuntimeError(f"recording failed: {recording.recorder.failed}")
        files.update(_read_tree(tmp / "bag", "bag"))
    if failure is not None:
        raise failure
