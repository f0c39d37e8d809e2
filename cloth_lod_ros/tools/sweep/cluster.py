"""Runs on ``dask.distributed``: the runner that ``cloth-lod sweep`` and
``cloth-lod bench --scheduler/--workers`` share.

* :func:`open_client`: a ``LocalCluster`` of one single-threaded worker
  process per allowed core (``threads_per_worker=1``; every BLAS, OpenMP and
  numba pool at one thread through the environment the nanny starts the worker
  with), or a client of an existing scheduler (``tcp://HOST:8786``: a
  ``dask scheduler`` with ``dask worker`` processes, or one that dask-jobqueue
  started on SLURM/PBS).
* :func:`check_workers`: every worker must import ``cloth_lod_ros`` at the
  version this process imports (asked with ``client.run``); the run fails
  early otherwise, naming the workers.  The probe is pickled by value, so a
  worker without the package answers instead of failing to unpickle it.
* :class:`Runner`: submits tasks (``retries``: a task whose worker died is
  re-run by Dask elsewhere; a worker lost while it ran is also rescheduled by
  the scheduler itself), yields results as they finish, draws the progress
  line, and on Ctrl-C cancels what is left (:meth:`Runner.cancel`).
* :func:`cpu_assignment`, :func:`cpu_lock`: the bench's pinning (one timed
  run at a time per core, each worker's runs pinned to its own core; the
  bench's pool, :mod:`cloth_lod_ros.tools.bench.pools`, uses them).

Reference: the Dask distributed documentation (``Client.submit``,
``Client.run``, ``LocalCluster``, ``distributed.wait``, ``distributed.Lock``).
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import time as _time
import uuid

__all__ = ["ClusterError", "THREAD_ENV", "LOCAL_HOUSEKEEPING", "open_client", "close", "check_workers", "Runner",
           "Progress", "cpu_assignment", "cpu_lock", "need_distributed"]

#: One thread in every pool a worker's libraries start.
THREAD_ENV = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                     "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
                                     "NUMEXPR_NUM_THREADS", "NUMBA_NUM_THREADS")}


#: Dask's periodic housekeeping in a local cluster, slowed (open_client says why).
LOCAL_HOUSEKEEPING = {"distributed.admin.tick.interval": "1s",
                      "distributed.admin.system-monitor.interval": "5s",
                      "distributed.worker.memory.monitor-interval": "1s"}


class ClusterError(RuntimeError):
    """No cluster, or workers that cannot run the package's tasks."""


def need_distributed():
    """``distributed``, or a ClusterError that says how to install it."""
    try:
        import distributed
    except ImportError:
        raise ClusterError("dask.distributed is not installed: pip install "
                           "'cloth_lod_ros[cluster]' (or pip install 'dask[distributed]')") \
            from None
    return distributed


def open_client(scheduler: str | None = None, workers: int | None = None,
                timeout: float = 60.0):
    """A client and the LocalCluster it runs on (None for an existing scheduler).

    Args:
        scheduler: ``tcp://HOST:PORT`` of a running scheduler, or None.
        workers: LocalCluster workers (default: one per allowed core); with a
            scheduler, wait until this many have joined (default 1).
        timeout: s to wait for the scheduler and its workers.
    """
    distributed = need_distributed()
    # distributed logs each connection at INFO: warnings and errors only.
    logging.getLogger("distributed").setLevel(logging.WARNING)
    if scheduler:
        try:
            client = distributed.Client(scheduler, timeout=timeout)
        except (OSError, TimeoutError) as exc:
            raise ClusterError(f"no Dask scheduler at {scheduler}: {exc}") from None
        try:
            client.wait_for_workers(workers or 1, timeout=timeout)
        except TimeoutError:
            client.close()
            raise ClusterError(f"the scheduler at {scheduler} has fewer than {workers or 1} "
                               f"worker(s) after {timeout:g} s (start some: dask worker "
                               f"{scheduler} --nthreads 1)") from None
        return client, None
    n = workers or len(os.sched_getaffinity(0))
    if n < 1:
        raise ClusterError("--workers must be at least 1")
    # Worker processes copy the environment at start: the thread limits must
    # be there before numpy loads its BLAS.
    # The scheduler's HTTP server (health, dashboard) on a free port of this
    # machine only: never the fixed 8787 another user's cluster may hold.
    # Ctrl-C in a terminal reaches the whole process group: the worker
    # processes start with SIGINT ignored (Python keeps an inherited SIG_IGN),
    # so only this process handles it - it cancels the runs and closes them.
    # The workers' statistical profiler samples the task thread's stack every
    # 10 ms under the GIL: 16 runs of the default scene stepped 26.8 s with it
    # and 21.3 s without (one worker, steps alone timed).  Without it, a run
    # takes the same CPU time in a worker as in a plain process when the two
    # are alternated run by run (docs/sweeps.md, "Speed").  An existing
    # cluster's workers keep theirs (docs/sweeps.md says how to turn it off).
    # Dask's housekeeping runs on timers in every process of a local cluster:
    # the event-loop tick (20 ms), the system monitor (0.5 s) and the memory
    # monitor (0.1 s).  Between them they took 2-3 % of a core in the client
    # process and again in each worker (an 8 s busy task, one worker; 0.4-0.8 %
    # each at the intervals below), CPU the runs' cores lose on a 2-core
    # machine.  The local workers and the scheduler and nannies in this
    # process run them at these slower intervals; an existing cluster keeps
    # its own settings.
    import dask
    env = dict(THREAD_ENV, DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED="False",
               **{"DASK_" + key.upper().replace(".", "__").replace("-", "_"): value
                  for key, value in LOCAL_HOUSEKEEPING.items()})
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with dask.config.set(LOCAL_HOUSEKEEPING):
            cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                               host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                               env=env, silence_logs=logging.ERROR)
    finally:
        signal.signal(signal.SIGINT, previous)
    return distributed.Client(cluster), cluster


def close(client, cluster) -> None:
    """Close the client, then the LocalCluster (if this process started one)."""
    for thing in (client, cluster):
        if thing is not None:
            try:
                thing.close()
            except Exception:           # closing after a failure: nothing more to do
                pass


def _make_probe(need_ros: bool):
    """The worker check, defined in a closure so that cloudpickle sends it by
    value (a worker without cloth_lod_ros can still run it)."""
    def probe():
        import os as _os
        import socket as _socket
        out = dict(host=_socket.gethostname(), pid=_os.getpid(),
                   cpus=sorted(_os.sched_getaffinity(0)))
        try:
            from cloth_lod_ros.tools.sweep.task import package_identity
            out.update(package_identity())
        except Exception as exc:                    # noqa: BLE001 - reported, not raised
            out["import_error"] = f"{type(exc).__name__}: {exc}"
            return out
        if need_ros:
            try:
                import rclpy  # noqa: F401
            except Exception as exc:                # noqa: BLE001
                out["ros_error"] = f"{type(exc).__name__}: {exc}"
        return out
    return probe


def check_workers(client, need_ros: bool = False, say=print) -> dict:
    """Ask every worker which ``cloth_lod_ros`` it imports; fail unless all
    import this process's version (and, with ``need_ros``, rclpy).

    Returns ``{worker address: {host, pid, cpus, version, fingerprint, path}}``.
    Raises ClusterError naming each worker that differs.  Workers whose
    sources differ at the same version (another checkout) get a warning.
    """
    from .task import package_identity
    mine = package_identity()
    answers = client.run(_make_probe(need_ros), on_error="return")
    bad, other_code = [], []
    for address, info in sorted(answers.items()):
        if isinstance(info, BaseException):
            bad.append(f"  {address}: the check failed: {type(info).__name__}: {info}")
        elif "import_error" in info:
            bad.append(f"  {address} ({info['host']}): cannot import cloth_lod_ros: "
                       f"{info['import_error']}")
        elif info["version"] != mine["version"]:
            bad.append(f"  {address} ({info['host']}): cloth_lod_ros {info['version']} at "
                       f"{info['path']}, this process has {mine['version']}")
        elif "ros_error" in info:
            bad.append(f"  {address} ({info['host']}): keep: bag needs rclpy "
                       f"(pip install 'cloth_lod_ros[ros]'): {info['ros_error']}")
        elif info["fingerprint"] != mine["fingerprint"]:
            other_code.append(f"{address} ({info['path']})")
    if not answers:
        raise ClusterError("the cluster has no workers")
    if bad:
        raise ClusterError("workers cannot run this sweep; install the same cloth_lod_ros "
                           "on every worker (pip install 'cloth_lod_ros[cluster]'):\n"
                           + "\n".join(bad))
    if other_code:
        say(f"warning: {len(other_code)} worker(s) import other sources of cloth_lod_ros "
            f"{mine['version']} than {mine['path']}: " + ", ".join(other_code[:4]))
    return answers


def cpu_assignment(answers: dict) -> dict:
    """``{worker address: CPU}`` for pinning: on each host, its workers (in
    address order) take that host's allowed CPUs in turn; a host with more
    workers than CPUs shares them (the runs then take turns: :func:`cpu_lock`)."""
    by_host: dict = {}
    for address, info in sorted(answers.items()):
        by_host.setdefault(info["host"], []).append((address, info["cpus"]))
    out = {}
    for host, workers in by_host.items():
        cpus = sorted(set().union(*(set(c) for _, c in workers)))
        for i, (address, _) in enumerate(workers):
            out[address] = cpus[i % len(cpus)]
    return out


def cpu_lock(host: str, cpu: int):
    """A cluster-wide lock for one core of one host: timed runs never share a core."""
    distributed = need_distributed()
    return distributed.Lock(f"cloth-lod-cpu-{host}-{cpu}")


class Progress:
    """``done/total`` with failures, elapsed and time left, on one stderr line
    (rewritten in place on a terminal; one line per finished run otherwise)."""

    def __init__(self, total: int, label: str = "sweep", quiet: bool = False,
                 stream=None):
        self.total, self.label, self.quiet = total, label, quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.done = self.failed = 0
        self.timed = 0                  # finished by running (the rate behind "left")
        self.start = _time.monotonic()
        self._last = 0.0

    def text(self) -> str:
        elapsed = _time.monotonic() - self.start
        left = "?"
        if self.timed:
            left = _clock(elapsed / self.timed * (self.total - self.done))
        elif self.done == self.total:
            left = _clock(0)
        pct = 100 * self.done / self.total if self.total else 100
        return (f"{self.label}: {self.done}/{self.total} done ({pct:.0f} %), "
                f"{self.failed} failed, {_clock(elapsed)} elapsed, ~{left} left")

    def update(self, done: int = 0, failed: int = 0, force: bool = False,
               instant: bool = False) -> None:
        """Count ``done`` more runs (``failed`` of them failed); ``instant``: they
        took no time (refused before running) and do not count towards the rate."""
        self.done += done
        self.failed += failed
        self.timed += 0 if instant else done
        if self.quiet:
            return
        now = _time.monotonic()
        if self.tty:
            if force or done or now - self._last > 1.0:
                self.stream.write("\r" + self.text() + "\033[K")
                self.stream.flush()
                self._last = now
        elif done or force:
            self.stream.write(self.text() + "\n")
            self.stream.flush()

    def close(self) -> None:
        if self.tty and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class Runner:
    """Tasks on a Dask client, yielded as they finish.

    Args:
        client: a ``distributed.Client``.
        retries: times Dask re-runs a task whose attempt raised (a task that
            catches its own errors raises only when its worker is lost).
    """

    def __init__(self, client, retries: int = 2):
        self.client = client
        self.retries = retries
        self.pending: dict = {}
        self._token = uuid.uuid4().hex[:8]

    def submit(self, fn, arg, name: str, priority: int = 0) -> None:
        """Submit ``fn(arg)``; ``name`` comes back with its result (unique per runner)."""
        future = self.client.submit(fn, arg, key=f"cloth-lod-{name}-{self._token}",
                                    pure=False, retries=self.retries, priority=priority)
        self.pending[future] = name

    def results(self, tick=None):
        """Yield ``(name, result, exception)`` as tasks finish (exception None on
        success); ``tick()`` is called about twice a second while waiting."""
        distributed = need_distributed()
        while self.pending:
            try:
                done, _ = distributed.wait(list(self.pending), timeout=0.5,
                                           return_when="FIRST_COMPLETED")
            except TimeoutError:
                if tick is not None:
                    tick()
                continue
            for future in done:
                name = self.pending.pop(future)
                if future.status == "finished":
                    result, error = future.result(), None
                else:
                    try:
                        error = future.exception() or RuntimeError(future.status)
                    except Exception as exc:    # cancelled: exception() raises
                        error = exc
                    result = None
                future.release()
                yield name, result, error

    def cancel(self) -> int:
        """Cancel every task not finished; return how many there were."""
        futures = list(self.pending)
        if futures:
            try:
                self.client.cancel(futures)
            except Exception:           # the scheduler may be gone already
                pass
        self.pending.clear()
        return len(futures)
