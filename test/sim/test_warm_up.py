"""The warm-up prepares the kernels a scene needs, and only those.

:func:`~cloth_lod_ros.sim.warm_up.warm_up_compiled_code` runs when a ClothSim is
built, so that no timed step (a node's frame, a benchmark's step) stops to compile
or load a kernel.  A signature first met later (another dtype, a read-only array, a
group the plan left out) is such a stop: none may appear while scenes with LOD,
contact, grasps, merges batched, self-collision and another integrator run.  Each
scene runs in a fresh process, so that kernels another scene loaded cannot hide a
gap in its own plan; the same processes check that the groups a scene does not need
were not compiled (no self-collision kernels with it off, no multigrid).
"""

from __future__ import annotations

import json
import logging
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from cloth_lod_ros.sim import warm_up
from cloth_lod_ros.sim.runtime import compiled
from cloth_lod_ros.sim.scene.config import load_scene, self_collision_on

pytestmark = pytest.mark.skipif(not compiled.available, reason="numba not installed")

REPO = Path(__file__).resolve().parents[2]     # the repository root

# In a fresh process: build the scene's simulator (its warm-up), count every
# kernel's signatures, step, count again; which modules' kernels have any.
RUN = """
import importlib, json, pkgutil, sys
import cloth_lod_ros.sim as sim_package
from cloth_lod_ros.sim import ClothSim, load_scene
from numba.core.registry import CPUDispatcher

def signatures():
    counts = {}
    for info in pkgutil.walk_packages(sim_package.__path__, sim_package.__name__ + "."):
        module = importlib.import_module(info.name)
        for value in vars(module).values():
            if isinstance(value, CPUDispatcher):
                f = value.py_func
                counts[f"{f.__module__.rsplit('.', 1)[-1]}.{f.__name__}"] = len(value.signatures)
    return counts

scene, overrides, steps = json.loads(sys.argv[1])
sim = ClothSim(load_scene(scene, overrides))
before = signatures()
for _ in range(steps):
    sim.step()
after = signatures()
print(json.dumps({"new": {k: [before.get(k), v] for k, v in after.items() if before.get(k) != v},
                  "modules": sorted({k.split(".")[0] for k, v in after.items() if v}),
                  "planned": [g.name for g in __import__("cloth_lod_ros.sim.warm_up",
                              fromlist=["GROUPS"]).GROUPS if g.needed(sim.scene)]}))
"""

CASES = [
    ("hang_two_corners", ["cloth.level=5"], 80),
    ("hang_two_corners", ["cloth.level=4", "lod.merge_interval=3"], 40),
    ("hang_two_corners", ["cloth.level=4", "lod.enabled=false",
                          "simulation.integrator=baraff_witkin"], 30),
    ("grasp_lift", ["cloth.level=4"], 60),
    ("drop_on_sphere", ["cloth.level=4"], 40),
    ("table_drape", [], 60),        # level 5: contact rounds on one factorisation (trailing)
    ("fold_in_half", ["cloth.level=4", "self_collision.enabled=true"], 40),
]


def _run(scene, overrides, steps) -> dict:
    proc = subprocess.run([sys.executable, "-c", RUN, json.dumps([scene, overrides, steps])],
                          cwd=REPO, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("scene, overrides, steps", CASES)
def test_a_scene_compiles_nothing_after_its_warm_up_and_only_what_it_needs(scene, overrides,
                                                                          steps):
    result = _run(scene, overrides, steps)
    assert result["new"] == {}, result["new"]
    config = load_scene(scene, overrides)
    assert ("self_broad_kernels" in result["modules"]) == self_collision_on(config)
    assert "multigrid_kernels" not in result["modules"]             # small cloths: direct
    assert ("hierarchy_kernels" in result["modules"]) == config.lod.enabled
    planned = set(result["planned"])
    assert ("trailing" in planned) == bool(config.obstacles or self_collision_on(config))


def test_plans_follow_the_scene():
    """Each optional group is in the plan exactly when its feature is: checked on
    scenes that differ from the default in that feature only."""
    def names(*overrides):
        return {g.name for g in warm_up.GROUPS if g.needed(load_scene("hang_two_corners",
                                                                         list(overrides)))}
    default = names("self_collision.enabled=false")
    assert names() == names("self_collision.enabled=auto") == names("self_collision.enabled=true")
    assert {"topology", "pattern", "projection", "step"} <= default
    assert not {"self", "multigrid", "trailing"} & default
    assert names("self_collision.enabled=true") - default == {"self", "trailing"}
    assert names("self_collision.enabled=false", "solver.method=multigrid") - default == {"multigrid"}
    assert default - names("self_collision.enabled=false", "lod.enabled=false") == {"hierarchy", "lod", "check", "round",
                                                    "compact"}
    # Uniform level 8 (4 x 4 blocks: 65 x 65 = 4,225 particles) is above auto's
    # direct limit: auto may switch to multigrid, so it is prepared.
    assert "multigrid" in names("cloth.level=8")
    assert warm_up._uniform_particles(load_scene("hang_two_corners", ["cloth.level=8"])) == 4225


def test_a_later_simulator_prepares_what_it_adds():
    """The process's second simulator, with self-collision on, prepares the
    self-collision group when it is built: its first step then compiles nothing."""
    code = RUN.replace("sim = ClothSim(load_scene(scene, overrides))",
                       "ClothSim(load_scene('hang_two_corners', ['self_collision.enabled=false']))\n"
                       "first = signatures()\n"
                       "sim = ClothSim(load_scene(scene, overrides))")
    code = code.replace('print(json.dumps({"new"',
                        'print(json.dumps({"self_before": sum(v for k, v in first.items() '
                        'if k.startswith("self_broad_kernels.")), "new"')
    proc = subprocess.run([sys.executable, "-c", code,
                           json.dumps(["fold_in_half", ["cloth.level=4"], 20])],
                          cwd=REPO, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["self_before"] == 0 and result["new"] == {}
    assert "self_broad_kernels" in result["modules"]


def _compile_events(reporter, names):
    for name in names:                   # a kernel whose callee compiles inside it
        reporter.on_start(name)
        reporter.on_start("arrayobj.callee")
        reporter.on_end()
        reporter.on_end()


def test_progress_lines_name_the_group_once_and_compiles_outside_a_warm_up(caplog):
    reporter = warm_up._Compiles()
    group = warm_up.GROUPS[0]
    caplog.set_level(logging.INFO, logger=warm_up.log.name)
    reporter.group = (1, 3, group)
    _compile_events(reporter, ["topology_kernels._hinges", "elements_kernels._adopt"])
    reporter.group = None
    _compile_events(reporter, ["self_broad_kernels.broad_boxes"])
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == f"compiling {group.label} (1/3), about {group.compile_s:.0f} s..."
    assert sum(group.label in line for line in lines) == 1
    assert reporter.kernels == 2                        # top-level kernels, not callees
    assert "compiling self_broad_kernels.broad_boxes (not prepared" in lines[1]
    assert lines[2].startswith("compiled self_broad_kernels.broad_boxes in ")
    assert len(lines) == 3


def test_a_long_compile_is_never_silent(caplog, monkeypatch):
    """While a group compiles, a line every HEARTBEAT seconds names the kernel."""
    monkeypatch.setattr(warm_up, "HEARTBEAT", 0.05)
    reporter = warm_up._Compiles()
    monkeypatch.setattr(warm_up, "_compiles", reporter)
    caplog.set_level(logging.INFO, logger=warm_up.log.name)
    reporter.group = (2, 5, warm_up.GROUPS[3])
    reporter.started = time.perf_counter()
    reporter.on_start("hierarchy_kernels._execute")         # compiling, not ended
    stop = threading.Event()
    beat = threading.Thread(target=warm_up._heartbeat, args=(stop,))
    beat.start()
    try:
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and not any(
                "still compiling" in r.getMessage() for r in caplog.records):
            time.sleep(0.02)
    finally:
        stop.set()
        beat.join()
    beats = [r.getMessage() for r in caplog.records if "still compiling" in r.getMessage()]
    assert beats and f"still compiling {warm_up.GROUPS[3].label}: " \
                     "hierarchy_kernels._execute" in beats[0]
