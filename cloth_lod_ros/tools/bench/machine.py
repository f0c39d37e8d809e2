"""The machine a bench suite ran on and the files a suite writes: the
lowest layer of the bench's suites (``--solvers``, ``--scenes``, ``--contact``,
``--local``), so that each suite and the report can use it without importing
the runner."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import subprocess
import time as _time
from pathlib import Path

import numpy as np

from .process import THREAD_VARIABLES, _package_root

__all__ = ["write_suite"]


def write_suite(out: Path, stem: str, rows: list, repeats: int, cpu: int, start: float,
                render) -> dict:
    """Write ``stem``.json and ``stem``.md (``render(result)``) for a suite
    of pinned runs (``--solvers``, ``--scenes``) started at ``start``
    (``time.time()``); return the result."""
    result = dict(machine=dict(_machine(cpu), processor=platform.processor(), cpu=cpu),
                  repeats=repeats, minutes=(_time.time() - start) / 60, rows=rows)
    (out / f"{stem}.json").write_text(json.dumps(result, indent=1))
    (out / f"{stem}.md").write_text(render(result))
    return result


def _version(distribution: str) -> str:
    """The installed version of ``distribution`` ("" if it is not installed)."""
    from importlib import metadata
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return ""


def _machine(cpu: int) -> dict:
    import scipy
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=_package_root(),
                                capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                                    cwd=_package_root(), capture_output=True, text=True,
                                    timeout=10).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        commit, dirty = "", False
    return dict(cpu_model=model, logical_cpus=os.cpu_count(), pinned_cpu=cpu,
                platform=platform.platform(), python=platform.python_version(),
                numpy=np.__version__, scipy=scipy.__version__, numba=_version("numba"),
                date=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                git_commit=commit + ("+dirty" if dirty else ""),
                threads={name: "1" for name in THREAD_VARIABLES})
