"""The first line of ``cloth-lod`` and ``cloth_lod_node``: compiling (a first start) or
loading the kernels, printed before the slow imports.

The cache check is held against numba itself: the directory its locator picks, and
whether it recompiles a function after its source changed.
"""

from __future__ import annotations

import importlib
import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

from cloth_lod_ros.ros import startup
from cloth_lod_ros.sim.runtime import compiled

REPO = Path(__file__).resolve().parent.parent
needs_numba = pytest.mark.skipif(not compiled.available, reason="numba not installed")


def _env(**extra) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    env.pop("CLOTH_LOD_KERNELS", None)
    env.update(extra)
    return env


@needs_numba
def test_the_kernel_modules_are_those_with_cached_kernels():
    import cloth_lod_ros.sim as sim_package
    from numba.core.registry import CPUDispatcher
    found = set()
    for info in pkgutil.walk_packages(sim_package.__path__, sim_package.__name__ + "."):
        module = importlib.import_module(info.name)
        for value in vars(module).values():
            if isinstance(value, CPUDispatcher) and value._cache.__class__.__name__ != \
                    "NullCache":
                found.add(value.py_func.__module__[len("cloth_lod_ros.sim."):]
                          .replace(".", "/"))
    assert found == set(startup.KERNEL_MODULES)


@needs_numba
@pytest.mark.parametrize("cache_dir", ["", "numba-cache"])
def test_the_cache_directory_is_numbas(tmp_path, cache_dir):
    """numba's own locator (``_Cache.cache_path``) for a kernel, with and
    without NUMBA_CACHE_DIR, in a fresh process (numba reads it at import)."""
    env = _env(NUMBA_CACHE_DIR=str(tmp_path / cache_dir) if cache_dir else "")
    code = ("from cloth_lod_ros.sim.physics import forces_kernels\n"
            "from cloth_lod_ros.ros import startup\n"
            "print(forces_kernels._membrane._cache.cache_path)\n"
            "print(startup.cache_directory(startup.SIM_DIR / 'physics'))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    numba_says, we_say = proc.stdout.split()
    assert Path(numba_says) == Path(we_say)


TINY = """
import numba

@numba.njit(cache=True)
def twice(x):
    return 2 * x
"""


@needs_numba
def test_fresh_means_what_numba_loads(tmp_path):
    """A module numba has compiled is fresh; after its source changes numba
    recompiles it, and it is no longer fresh; in another cache it is missing."""
    package = tmp_path / "tinypkg"
    package.mkdir()
    (package / "tiny.py").write_text(TINY)
    env = _env(NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join((str(tmp_path), str(REPO))))
    run = ("import json\nfrom pathlib import Path\n"
           "from cloth_lod_ros.sim.runtime import compiled\n"
           f"compiled.key_caches_on_package(Path({str(package)!r}))\n"
           "import tiny\n"
           "tiny.twice(3)\n"
           "print(json.dumps([sum(tiny.twice.stats.cache_hits.values()),"
           " sum(tiny.twice.stats.cache_misses.values())]))\n")

    def numba_run():
        proc = subprocess.run([sys.executable, "-c", run], cwd=package, env=env,
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout)

    def ours():
        code = ("import json\nfrom pathlib import Path\nfrom cloth_lod_ros.ros import startup\n"
                f"c = startup.kernel_cache(Path({str(package)!r}), ('tiny',))\n"
                "print(json.dumps([c.state, str(c.directory)]))\n")
        proc = subprocess.run([sys.executable, "-c", code], env={**env, "PYTHONPATH": str(REPO)},
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout)

    assert ours()[0] == "cold"
    assert numba_run() == [0, 1]                    # compiled
    assert ours()[0] == "warm"
    assert numba_run() == [1, 0]                    # loaded
    (package / "tiny.py").write_text(TINY.replace("2 * x", "x + x + 0"))
    assert ours()[0] == "cold"
    assert numba_run() == [0, 1]                    # numba agrees: compiled again
    assert ours()[0] == "warm"
    assert Path(ours()[1]) == tmp_path / "cache"      # the root of the per-folder caches


def test_the_first_line_comes_before_the_slow_imports():
    """What runs before the first line imports none of numba, scipy, rclpy: the
    CLI's module and this one (a structural check; no timing)."""
    code = ("import sys\nimport cloth_lod_ros.tools.cli, cloth_lod_ros.ros.startup\n"
            "print(sorted({m.split('.')[0] for m in sys.modules} & "
            "{'numba', 'scipy', 'rclpy', 'llvmlite', 'matplotlib'}))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def _first_stderr_line(args, env, cwd) -> tuple[str, subprocess.Popen]:
    proc = subprocess.Popen(args, cwd=cwd, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    return proc.stderr.readline(), proc


def _stop(proc):
    if proc.poll() is None:
        proc.kill()
    proc.wait(timeout=30)
    proc.stderr.close()


RUN = ["run", "hang_two_corners", "--frames", "1", "--duration", "0.05", "--no-png", "--quiet"]


@needs_numba
def test_a_first_start_says_it_compiles_first(tmp_path):
    """An empty cache: the first stderr line says it compiles, for how long,
    and where the cache goes; stopped there (the compile itself takes a minute)."""
    cache = tmp_path / "cache"
    line, proc = _first_stderr_line(
        [sys.executable, "-m", "cloth_lod_ros.tools.cli", *RUN, "--out", str(tmp_path / "s.npz")],
        _env(NUMBA_CACHE_DIR=str(cache)), tmp_path)
    try:
        assert line.startswith("cloth-lod: preparing compiled kernels: first start"), line
        assert "compiling numba kernels" in line and f"about {startup.FIRST_START_S} s" in line
        assert str(cache) in line
    finally:
        _stop(proc)


@needs_numba
def test_the_node_says_it_first_too(tmp_path):
    """``cloth_lod_node`` (startup.node_main) on an empty cache, before rclpy."""
    code = "from cloth_lod_ros.ros.startup import node_main\nnode_main()\n"
    line, proc = _first_stderr_line(
        [sys.executable, "-c", code, "--ros-args", "-p", "scene:=hang_two_corners"],
        _env(NUMBA_CACHE_DIR=str(tmp_path / "cache"), ROS_DOMAIN_ID="231",
             ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"), tmp_path)
    try:
        assert line.startswith("cloth_lod_node: preparing compiled kernels: first start"), line
    finally:
        _stop(proc)


@needs_numba
def test_a_warm_start_says_it_loads_and_when_it_is_ready(tmp_path):
    """Every group prepared in this process (so cached where numba caches for
    this checkout): the CLI's first line says it loads them, a later line says
    they were loaded, and no line says compiling."""
    from cloth_lod_ros.sim import ClothSim, warm_up
    warm_up.warm_up_compiled_code(ClothSim)         # every group, in every variant
    assert startup.kernel_cache().state == "warm"
    proc = subprocess.run([sys.executable, "-m", "cloth_lod_ros.tools.cli", *RUN,
                           "--out", str(tmp_path / "s.npz")], cwd=tmp_path, env=_env(),
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert lines[0].startswith("cloth-lod: preparing compiled kernels: loading them from "
                               "numba's cache"), lines
    assert any(line.startswith("cloth-lod: compiled kernels loaded from the cache in ")
               for line in lines), lines
    assert not any("compiling" in line for line in lines), lines


def test_the_line_for_each_state():
    directory = Path("/cache")
    cold = startup.kernel_notice(startup.KernelCache(directory, (), ("a", "b")))
    warm = startup.kernel_notice(startup.KernelCache(directory, ("a", "b"), ()))
    partial = startup.kernel_notice(startup.KernelCache(directory, ("a",), ("b",)))
    off = startup.kernel_notice(startup.KernelCache(directory, (), ("a", "b"), numba=False))
    assert "first start" in cold and "/cache" in cold
    assert "loading them from numba's cache" in warm and "first start" not in warm
    assert "1 of 2" in partial and "(b)" in partial
    assert "numpy reference code" in off


def test_the_first_start_estimate_is_the_default_scenes_plan():
    """FIRST_START_S is the default scene's groups' measured compile times added up."""
    from cloth_lod_ros.sim import warm_up
    from cloth_lod_ros.sim.scene.config import load_scene
    scene = load_scene("hang_two_corners")
    total = sum(g.compile_s for g in warm_up.GROUPS if g.needed(scene))
    assert abs(total - startup.FIRST_START_S) <= 5, total


def test_the_node_entry_point_is_the_one_that_prints_first():
    text = (REPO / "setup.py").read_text()
    assert "cloth_lod_node = cloth_lod_ros.ros.startup:node_main" in text
    assert "cloth-lod = cloth_lod_ros.tools.cli:main" in text


def test_the_node_refuses_a_scene_over_budget_before_its_imports(tmp_path):
    """``cloth_lod_node --ros-args -p scene:=FILE`` checks FILE before the kernel line
    and the imports of rclpy and numba (issue 34): one line, exit code 2."""
    scene = tmp_path / "big.yaml"
    scene.write_text("cloth: {width: 1, height: 1, base_blocks: [4, 4], level: 12}\n"
                     "simulation: {time_step: 0.02, duration: 1}\n")
    code = ("import sys\nfrom cloth_lod_ros.ros.startup import node_main\ntry:\n"
            "    node_main()\nfinally:\n"
            "    print(sorted({m.split('.')[0] for m in sys.modules} & "
            "{'numba', 'scipy', 'rclpy'}))\n")
    proc = subprocess.run([sys.executable, "-c", code, "--ros-args", "-p", f"scene:={scene}"],
                          cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("cloth_lod_node: scene error: "), lines
    assert "the limit is 32,768 triangles" in lines[0]
    assert proc.stdout.strip() == "[]"
