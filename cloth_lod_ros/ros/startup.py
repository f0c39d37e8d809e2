"""A process's first line: are the numba kernels compiled (first start) or loaded from the cache?

``cloth_lod_node`` and ``cloth-lod`` print this line before they import numpy, scipy,
numba or rclpy, which alone take 2-3 s on a busy 2-core machine; the kernels a scene
needs then take about a second to load from numba's cache, or the better part of a
minute to compile on a machine's first start (``sim/warm_up.py``, which reports each
group of kernels as it compiles).  This module therefore imports only the standard
library, and tells a first start from a warm one the way numba does, without
importing it: numba keeps one index file per compiled function
(``<module>.<function>-<line>.py<XY>.nbi``) whose first pickle is the numba version
and whose payload holds the SHA-256 of the module's source when it was compiled
(``numba/core/caching.py``: ``IndexDataCacheFile._load_index``, ``get_source_stamp``);
an index with another version or another source is ignored and the function
recompiled.  The directory is the one numba's locators pick (the same file, the
``_CacheLocator`` classes in their order): ``$NUMBA_CACHE_DIR/<dir>_<sha1 of dir>``
when that variable is set, else ``__pycache__`` beside the module when writable (a
checkout, a venv's site-packages after ``pip install .``), else the user's cache
directory (``~/.cache/numba/<dir>_<sha1>`` on Linux: a read-only install).

Not covered (the later lines tell): an index written on another CPU model (numba keys
the compiled code by CPU), a kernel of a cached module that no earlier process used.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import sys
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["KERNEL_MODULES", "FIRST_START_S", "PREFIX", "KernelCache", "cache_directory",
           "kernel_cache", "kernel_notice", "announce", "node_main"]

#: The modules of ``cloth_lod_ros.sim`` with ``cache=True`` kernels, as paths
#: relative to ``sim/`` without ``.py`` (``test/test_startup.py`` checks the
#: list against the package).  numba caches each beside its own part's folder.
KERNEL_MODULES = ("contact/self_broad_kernels", "inputs/holding_kernels",
                  "lod/check_kernels", "lod/merge_bend_kernels", "lod/merge_energy_kernels",
                  "lod/policy_kernels",
                  "lod/round_kernels", "mesh/compact_kernels", "mesh/hierarchy_kernels",
                  "mesh/int_table", "mesh/topology_kernels", "physics/elements_kernels",
                  "physics/energies_kernels", "physics/forces_kernels",
                  "physics/hinges_kernels", "solve/block_ldl", "solve/multigrid_kernels",
                  "solve/pattern_kernels", "solve/projection_kernels", "solve/trailing_ldl")
#: s: compiling the default scene's kernels from an empty cache, measured as CPU time
#: (numba compiles on one core) on a 2-core x86_64 machine (AMD EPYC, numba 0.68):
#: ``warm_up.GROUPS``' estimates for ``hang_two_corners`` added up (the test checks).
FIRST_START_S = 100     # self-collision (`auto`, the default) adds its kernels

#: How the line starts, whatever it says.
PREFIX = "preparing compiled kernels: "
SIM_DIR = Path(__file__).resolve().parent.parent / "sim"
WARM_UP_LOGGER = "cloth_lod_ros.sim.warm_up"


@dataclass(frozen=True)
class KernelCache:
    """What numba's cache holds for the simulator's kernel modules."""
    directory: Path             # where numba reads and writes them
    fresh: tuple                # modules with an index for this numba and this source
    missing: tuple              # modules without one: compiled when first used
    numba: bool = True          # numba installed and the kernels enabled

    @property
    def state(self) -> str:
        """``"off"`` (numpy reference code), ``"cold"`` (nothing cached: a
        first start), ``"warm"`` (every module cached) or ``"partial"``."""
        if not self.numba:
            return "off"
        return "cold" if not self.fresh else "warm" if not self.missing else "partial"


def _subpath(source_dir: Path) -> str:
    # numba's _CacheLocator.get_suitable_cache_subpath: the directory's name and
    # the SHA-1 of its absolute path.
    path = os.path.abspath(source_dir)
    return f"{os.path.basename(path)}_{hashlib.sha1(path.encode()).hexdigest()}"


def _user_cache_dir() -> Path:
    # numba.misc.appdirs.user_cache_dir("numba", appauthor=False)
    if sys.platform == "darwin":
        return Path("~/Library/Caches/numba").expanduser()
    if sys.platform == "win32":
        return Path(os.environ.get("LOCALAPPDATA", "~")).expanduser() / "numba" / "Cache"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path("~/.cache").expanduser()) / "numba"


def _writable(directory: Path) -> bool:
    existing = directory
    while not existing.exists():
        existing = existing.parent
    return os.access(existing, os.W_OK | os.X_OK)


def cache_directory(source_dir: Path = SIM_DIR) -> Path:
    """Where numba caches the kernels of the modules in ``source_dir``."""
    user_dir = os.environ.get("NUMBA_CACHE_DIR", "")
    if user_dir:
        return Path(user_dir) / _subpath(source_dir)
    in_tree = Path(source_dir) / "__pycache__"
    if _writable(in_tree):
        return in_tree
    return _user_cache_dir() / _subpath(source_dir)


def _shown_directory(source_dir: Path) -> Path:
    """Where the kernels' caches are, for the first line: numba keeps one per
    folder of kernel modules, so beside the package ``sim/*/__pycache__``."""
    folder = cache_directory(Path(source_dir) / "mesh")
    if folder.name == "__pycache__":
        return Path(source_dir) / "*" / "__pycache__"
    return folder.parent


def package_stamp(root: Path) -> bytes:
    """The key numba's cache holds for every kernel under ``root``: the SHA-256
    of all its sources (``sim/runtime/compiled.py``'s ``package_stamp``, which
    this must equal: ``test/test_startup.py``; not imported from there, as
    importing the simulator is what this module prints before)."""
    digest = hashlib.sha256()
    for path in sorted(p for p in Path(root).rglob("*.py") if "__pycache__" not in p.parts):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.digest()


def _numba_version() -> str | None:
    """The installed numba's version, or None: from its ``dist-info`` beside
    the package (importlib.metadata scans every distribution: 0.1 s here)."""
    from importlib.util import find_spec
    spec = find_spec("numba")
    if spec is None or not spec.origin:
        return None
    infos = list(Path(spec.origin).parent.parent.glob("numba-*.dist-info"))
    if len(infos) == 1:
        return infos[0].name[len("numba-"):-len(".dist-info")]
    from importlib import metadata
    try:
        return metadata.version("numba")
    except metadata.PackageNotFoundError:
        return None


def _fresh(index: Path, version: str, digest: bytes) -> bool:
    try:
        with open(index, "rb") as f:
            if pickle.load(f) != version:       # a str: numba's version
                return False
            return digest in f.read()           # the package's stamp, as the kernels' locators key it
    except (OSError, pickle.UnpicklingError, EOFError, ValueError):
        return False


def kernel_cache(source_dir: Path = SIM_DIR, modules: tuple = KERNEL_MODULES) -> KernelCache:
    """Which of ``modules`` (in ``source_dir``) numba's cache holds for the
    installed numba and the sources as they are now (a few ms: the index files
    of each module are read until a fresh one is found)."""
    directory = _shown_directory(source_dir)
    version = _numba_version()
    if version is None or os.environ.get("CLOTH_LOD_KERNELS", "auto").lower() == "numpy":
        return KernelCache(directory, (), tuple(modules), numba=False)
    suffix = f".py{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, 'abiflags', '')}.nbi"
    listed = {}                 # cache directory -> its index files
    fresh, missing = [], []
    digest = package_stamp(Path(source_dir))
    for module in modules:
        source = Path(source_dir) / f"{module}.py"
        if not source.is_file():
            missing.append(module)
            continue
        folder = cache_directory(source.parent)
        if folder not in listed:
            try:
                listed[folder] = [n for n in os.listdir(folder) if n.endswith(suffix)]
            except OSError:
                listed[folder] = []
        name = source.stem
        indexes = (folder / n for n in listed[folder] if n.startswith(f"{name}."))
        (fresh if any(_fresh(i, version, digest) for i in indexes) else missing).append(module)
    return KernelCache(directory, tuple(fresh), tuple(missing))


def kernel_notice(cache: KernelCache) -> str:
    """The first line's text for ``cache``."""
    if cache.state == "off":
        return (f"{PREFIX}none (numba is not installed, or CLOTH_LOD_KERNELS=numpy): the "
                "numpy reference code runs, slower")
    if cache.state == "cold":
        return (f"{PREFIX}first start on this machine, compiling numba kernels (once; about "
                f"{FIRST_START_S} s on an idle 2-core machine, longer on a busy one; cached "
                f"in {cache.directory})...")
    if cache.state == "partial":
        return (f"{PREFIX}loading them from numba's cache in {cache.directory}; "
                f"{len(cache.missing)} of {len(cache.missing) + len(cache.fresh)} kernel "
                "modules were never compiled here and are compiled if the scene needs them "
                f"({', '.join(cache.missing)})...")
    return f"{PREFIX}loading them from numba's cache in {cache.directory}..."


def announce(prog: str, log_to_stderr: bool = True) -> KernelCache:
    """Print the first line on stderr; with ``log_to_stderr``, also send the
    warm-up's progress lines (the logger of ``sim/warm_up.py``, INFO) to stderr,
    prefixed ``prog: ``."""
    cache = kernel_cache()
    print(f"{prog}: {kernel_notice(cache)}", file=sys.stderr, flush=True)
    if log_to_stderr:
        import logging

        class Stderr(logging.Handler):      # sys.stderr as it is when a line is logged
            def emit(self, record):
                print(self.format(record), file=sys.stderr, flush=True)

        logger = logging.getLogger(WARM_UP_LOGGER)
        logger.handlers = [h for h in logger.handlers if type(h).__name__ != "Stderr"]
        handler = Stderr()
        handler.setFormatter(logging.Formatter(f"{prog}: %(message)s"))
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        logger.propagate = False
    return cache


def _scene_argument(argv) -> str | None:
    """The value of ``-p scene:=VALUE`` (or ``--param``) on a ROS command line, if any
    (the last one wins, as in rcl)."""
    value = None
    for flag, item in zip(argv, argv[1:]):
        if flag in ("-p", "--param") and item.startswith("scene:="):
            value = item[len("scene:="):]
    return value


def node_main(args=None) -> None:
    """Entry point ``cloth_lod_node``: the first line, then the node
    (:func:`cloth_lod_ros.ros.node.main`, whose imports take the seconds after it).

    A scene given on the command line (``-p scene:=...``) is checked first: one that
    is refused (a bad file, or over the cost budget, ``sim/scene/budget.py``) is
    said in one line, exit code 2, before those imports (the node checks the scene
    again, wherever it comes from)."""
    start = time.monotonic()
    scene = _scene_argument(sys.argv if args is None else list(args))
    if scene:
        from ..sim.scene.config import SceneError, load_scene     # PyYAML only
        try:
            load_scene(scene)
        except SceneError as exc:
            print(f"cloth_lod_node: scene error: {exc}", file=sys.stderr)
            raise SystemExit(2) from None
    announce("cloth_lod_node", log_to_stderr=False)     # the node logs on the ROS logger
    from .node import main
    main(args, started=start)
