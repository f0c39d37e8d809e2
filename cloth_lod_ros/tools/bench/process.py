"""One benchmark run in a fresh single-threaded process (``cloth-lod bench``).

:func:`run_in_process` writes the run's spec, starts ``python -m
cloth_lod_ros.tools.bench --worker SPEC.json`` (:mod:`.worker`: pinned to a
core before any work) with every thread pool at one thread, and reads the
result back.  The bench's local pool and its Dask pool (:mod:`.pools`) both
call it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from .plan import BenchError

__all__ = ["THREAD_VARIABLES", "run_in_process"]

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def _package_root() -> str:
    """The directory that holds the ``cloth_lod_ros`` package (the repository root
    for a source tree), so workers import the same code as this process."""
    return str(Path(__file__).resolve().parents[3])


def run_in_process(spec: dict, workdir: Path, tag: str) -> dict:
    """Run ``spec`` in a fresh single-threaded process; return its result."""
    spec_path = workdir / f"{tag}.spec.json"
    result_path = workdir / f"{tag}.result.json"
    spec = dict(spec, result=str(result_path))
    spec_path.write_text(json.dumps(spec))
    env = dict(os.environ)
    for name in THREAD_VARIABLES:
        env[name] = "1"
    env["PYTHONPATH"] = os.pathsep.join(
        [_package_root()] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    proc = subprocess.run([sys.executable, "-m", "cloth_lod_ros.tools.bench", "--worker",
                           str(spec_path)], env=env, capture_output=True, text=True)
    if proc.returncode != 0 or not result_path.exists():
        tail = "\n".join(proc.stderr.strip().splitlines()[-15:])
        raise BenchError(f"worker {tag} failed (exit {proc.returncode}):\n{tail}")
    return json.loads(result_path.read_text())
