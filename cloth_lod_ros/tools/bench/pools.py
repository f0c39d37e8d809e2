"""Where the bench's runs run: in turn on this machine's ``--cpu``
(:class:`LocalPool`), or as tasks on Dask workers (:class:`PinnedDaskPool`),
each in a fresh single-threaded process pinned to one core
(:func:`.process.run_in_process`).  Both take ``(key, spec, tag)`` jobs and
yield ``(key, result)``.  The Dask plumbing (client, worker check, runner,
per-core locks) is the sweep's, :mod:`cloth_lod_ros.tools.sweep.cluster`.
"""

from __future__ import annotations

import os
import time as _time
from pathlib import Path

from ..sweep.cluster import (ClusterError, Runner, check_workers, close, cpu_assignment,
                             cpu_lock, open_client)
from .plan import BenchError
from .process import run_in_process

__all__ = ["LocalPool", "PinnedDaskPool", "make_pool"]


class LocalPool:
    """The bench's own runner: each run in turn, in a fresh process pinned to
    ``--cpu`` (:func:`run_in_process`).  ``map`` yields ``(key, result)``."""

    workers = None
    workdir: Path

    def map(self, jobs):
        for key, spec, tag in jobs:
            t0 = _time.perf_counter()
            result = run_in_process(spec, self.workdir, tag)
            result["process_s"] = _time.perf_counter() - t0
            yield key, result

    def close(self) -> None:
        pass


def make_pool(args):
    """Where the runs run: this machine's ``--cpu`` (default), or Dask workers
    (``--scheduler``/``--workers``: each run in a fresh process pinned to its
    worker's core, one timed run per core at a time;
    :class:`PinnedDaskPool`)."""
    if getattr(args, "scheduler", None) or getattr(args, "workers", None):
        return PinnedDaskPool(args.scheduler, args.workers, say=print)
    return LocalPool()


def _pinned_task(payload: dict) -> dict:
    """On a worker: one ``cloth-lod bench`` run in a fresh process pinned to
    this worker's core (``run_in_process``: one thread, pinned before
    any work), taking turns with any other run on that core; returns the run's
    result with ``worker``, ``host`` and ``cpu``."""
    import socket
    import tempfile
    from pathlib import Path
    from distributed import get_worker
    address = get_worker().address
    host = socket.gethostname()
    allowed = sorted(os.sched_getaffinity(0))
    cpu = payload["cpus"].get(address)
    if cpu not in allowed:                  # a worker that joined after the assignment
        cpu = allowed[0]
    with tempfile.TemporaryDirectory(prefix="cloth_lod_bench_") as tmp:
        spec = dict(payload["spec"], cpu=cpu)
        if payload.get("scene_text") is not None:   # workers need not share our files
            scene_file = Path(tmp) / payload["scene_name"]
            scene_file.write_text(payload["scene_text"])
            spec["scene"] = str(scene_file)
        with cpu_lock(host, cpu):
            start = _time.perf_counter()
            result = run_in_process(spec, Path(tmp), payload["tag"])
            result["process_s"] = _time.perf_counter() - start
    result.update(worker=address, host=host, cpu=cpu)
    return result


class PinnedDaskPool:
    """``cloth-lod bench`` runs on Dask workers, each in a fresh pinned process
    (:func:`_pinned_task`): a LocalCluster (``workers``) or a scheduler.

    :meth:`map` takes ``(key, spec, tag)`` jobs and yields ``(key, result)`` as
    they finish; a run that fails raises the bench's BenchError.  ``workers``
    (after opening) maps each worker's address to its host and CPU.
    """

    def __init__(self, scheduler: str | None, workers: int | None, retries: int = 1,
                 say=print):
        self.client, self.cluster = open_client(scheduler, workers)
        try:
            answers = check_workers(self.client, say=say)
        except ClusterError:
            close(self.client, self.cluster)
            raise
        self.cpus = cpu_assignment(answers)
        self.workers = {a: dict(host=answers[a]["host"], cpu=c) for a, c in self.cpus.items()}
        self.runner = Runner(self.client, retries=retries)
        self._scenes: dict = {}

    def _scene(self, scene: str) -> tuple:
        """The scene file's name and text (None for a built-in name)."""
        from pathlib import Path
        if scene not in self._scenes:
            path = Path(scene)
            self._scenes[scene] = (path.name, path.read_text()) if path.is_file() else (
                None, None)
        return self._scenes[scene]

    def map(self, jobs):
        keys = {}
        for i, (key, spec, tag) in enumerate(jobs):
            name, text = self._scene(spec["scene"])
            payload = dict(spec=spec, tag=tag, cpus=self.cpus, scene_name=name,
                           scene_text=text)
            keys[f"{i}-{tag}"] = key
            self.runner.submit(_pinned_task, payload, f"{i}-{tag}")
        for name, result, error in self.runner.results():
            if error is not None:
                self.runner.cancel()
                raise BenchError(f"run {name.split('-', 1)[1]} failed on the cluster: "
                                 f"{type(error).__name__}: {error}")
            yield keys[name], result

    def close(self) -> None:
        self.runner.cancel()
        close(self.client, self.cluster)
