"""The package's layers (docs/design.md §9): imports point down only.

sim < messages < bag < live < ros < tools.  The simulator must import without rclpy,
mcap or matplotlib installed; the MCAP code must not need rclpy to read or
write a bag; the message builders never touch mcap.

Inside the simulator the parts are ordered too (:data:`SIM_PARTS`, bottom to
top, the facade above them all), and no module of the package imports, at
any depth and through any chain, a module that imports it back.
"""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "cloth_lod_ros"
LAYERS = ("sim", "messages", "bag", "live", "ros", "tools")
#: The simulator's parts, bottom to top (docs/design.md §9): a module of one
#: imports from its own part and the ones before it only.  The facade -
#: ``sim/__init__.py``, ``cloth.py`` (ClothSim) and ``warm_up.py`` - is on top.
SIM_PARTS = ("runtime", "scene", "mesh", "physics", "solve", "contact", "integrate", "lod",
             "inputs")
SIM_FACADE = ("__init__", "cloth", "warm_up")
# Third-party modules a layer (or one module) must never import, even lazily.
FORBIDDEN = {
    "sim": {"rclpy", "mcap", "matplotlib", "rosidl_runtime_py"},
    "messages": {"mcap", "matplotlib"},
    "bag/rosbag.py": {"rclpy"},
    "live": {"rclpy", "mcap"},        # the live view serves a pip install without ROS
}


def _modules():
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def _layer(path: Path) -> str | None:
    parts = path.relative_to(PACKAGE).parts
    return parts[0] if len(parts) > 1 and parts[0] in LAYERS else None


def _imports(path: Path):
    """``(lineno, absolute module name)`` of every import in ``path``, at any depth."""
    package = ["cloth_lod_ros", *path.relative_to(PACKAGE).parent.parts]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            if node.module is None:       # "from . import x": x is a module
                for alias in node.names:
                    yield node.lineno, f"{module}.{alias.name}"
            else:
                yield node.lineno, module


def test_every_module_belongs_to_a_layer():
    strays = [str(p.relative_to(PACKAGE)) for p in _modules()
              if _layer(p) is None and p.name != "__init__.py"]
    assert strays == []


def test_imports_inside_the_package_point_down():
    wrong = []
    for path in _modules():
        layer = _layer(path)
        if layer is None:
            continue
        for lineno, module in _imports(path):
            parts = module.split(".")
            if parts[0] != "cloth_lod_ros" or len(parts) < 2 or parts[1] not in LAYERS:
                continue
            if LAYERS.index(parts[1]) > LAYERS.index(layer):
                wrong.append(f"{path.relative_to(PACKAGE)}:{lineno} ({layer}) imports {module}")
    assert wrong == []


def test_forbidden_third_party_imports_appear_nowhere_in_the_source():
    wrong = []
    for path in _modules():
        rel = path.relative_to(PACKAGE).as_posix()
        banned = FORBIDDEN.get(rel, set()) | FORBIDDEN.get(_layer(path) or "", set())
        for lineno, module in _imports(path):
            if module.split(".")[0] in banned:
                wrong.append(f"{rel}:{lineno} imports {module}")
    assert wrong == []


def test_the_import_checker_sees_relative_and_lazy_imports(monkeypatch):
    """The checks above would pass vacuously if ``_imports`` missed the forms the
    package uses; feed it each form."""
    fake = PACKAGE / "sim" / "example.py"
    source = ("from ..tools import cli\nfrom . import forces\nimport numpy\n"
              "def f():\n    import rclpy\n    from mcap.writer import Writer\n")
    monkeypatch.setattr(Path, "read_text", lambda self: source)
    found = {m for _, m in _imports(fake)}
    assert {"cloth_lod_ros.tools", "cloth_lod_ros.sim.forces", "numpy", "rclpy",
            "mcap.writer"} <= found


def _module_name(path: Path) -> str:
    parts = [PACKAGE.name, *path.relative_to(PACKAGE).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _internal_imports(path: Path, source: str, modules: set[str]):
    """``(lineno, module)`` of every import of a module of ``modules`` in
    ``source`` (the file at ``path``), at any depth, relative ones resolved;
    ``from package import module`` is an import of that module."""
    package = [PACKAGE.name, *path.relative_to(PACKAGE).parent.parts]
    for node in ast.walk(ast.parse(source, str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                name = alias.name
                while name and name not in modules:
                    name = name.rpartition(".")[0]
                if name:
                    yield node.lineno, name
        elif isinstance(node, ast.ImportFrom):
            base = node.module if not node.level else ".".join(
                package[:len(package) - (node.level - 1)] + ([node.module] if node.module else []))
            for alias in node.names:
                if f"{base}.{alias.name}" in modules:
                    yield node.lineno, f"{base}.{alias.name}"
                elif base in modules:
                    yield node.lineno, base


def _import_graph(sources: dict[Path, str]) -> dict[str, list[tuple[str, str]]]:
    """module -> ``[(imported module, "file:line")]`` within the package."""
    names = {path: _module_name(path) for path in sources}
    modules = set(names.values())
    graph = {name: [] for name in modules}
    for path, source in sources.items():
        rel = path.relative_to(PACKAGE)
        for lineno, module in _internal_imports(path, source, modules):
            if module != names[path]:
                graph[names[path]].append((module, f"{rel}:{lineno}"))
    return graph


def _cycles(graph: dict[str, list[tuple[str, str]]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan):
    each a set of modules that import each other through some chain."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w, _ in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _sim_part(module: str) -> int | None:
    """The rank of a simulator module's part (SIM_PARTS, the facade last), or
    None outside the simulator."""
    parts = module.split(".")
    if parts[:2] != [PACKAGE.name, "sim"]:
        return None
    return SIM_PARTS.index(parts[2]) if len(parts) > 2 and parts[2] in SIM_PARTS \
        else len(SIM_PARTS)


def import_problems(sources: dict[Path, str] | None = None) -> list[str]:
    """Every import cycle and every import up the simulator's parts, one line
    each (empty when the imports point one way)."""
    if sources is None:
        sources = {p: p.read_text() for p in _modules()}
    graph = _import_graph(sources)
    problems = []
    for component in _cycles(graph):
        inside = [f"{where} ({m} -> {t})" for m in component for t, where in graph[m]
                  if t in component]
        problems.append("import cycle among " + ", ".join(component) + ": "
                        + "; ".join(inside))
    for module, edges in sorted(graph.items()):
        rank = _sim_part(module)
        for target, where in edges:
            if rank is not None and _sim_part(target) is not None and _sim_part(target) > rank:
                problems.append(f"{where}: {module} imports {target}, a higher part of sim")
    return problems


def test_every_simulator_module_is_in_a_declared_part():
    strays = []
    for path in (PACKAGE / "sim").rglob("*.py"):
        parts = path.relative_to(PACKAGE / "sim").with_suffix("").parts
        if "__pycache__" in parts:
            continue
        if (len(parts) == 1 and parts[0] not in SIM_FACADE) or (
                len(parts) > 1 and parts[0] not in SIM_PARTS):
            strays.append("/".join(parts))
    assert strays == []


def test_no_import_cycles_and_no_import_up_the_simulators_parts():
    assert import_problems() == []


def test_the_cycle_and_part_checks_see_lazy_relative_imports():
    """The check above would pass vacuously if it missed the forms the package
    uses: a lazy relative import in a lower part that closes a cycle."""
    sim = PACKAGE / "sim"
    sources = {sim / "mesh" / "example_low.py": "def f():\n    from ..lod import example_high\n",
               sim / "lod" / "example_high.py": "from ..mesh.example_low import f\n",
               sim / "lod" / "example_free.py": "from ..mesh import example_low\n"}
    problems = import_problems(sources)
    assert len(problems) == 2, problems
    assert problems[0].startswith("import cycle among cloth_lod_ros.sim.lod.example_high, "
                                  "cloth_lod_ros.sim.mesh.example_low")
    assert problems[1].startswith("sim/mesh/example_low.py:2: cloth_lod_ros.sim.mesh.example_low "
                                  "imports cloth_lod_ros.sim.lod.example_high")


BLOCKER = """
import importlib.abc, json, sys
BLOCKED = {blocked!r}
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ImportError(f"{{name}} is blocked in this test")
        return None
sys.meta_path.insert(0, Block())
import importlib
for name in {modules!r}:
    importlib.import_module(name)
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)))
"""


def _import_blocked(modules: list[str], blocked: set[str]) -> subprocess.CompletedProcess:
    code = BLOCKER.format(blocked=sorted(blocked), modules=modules)
    return subprocess.run([sys.executable, "-c", code], cwd=PACKAGE.parent,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("layer, blocked", [
    ("sim", {"rclpy", "mcap", "matplotlib"}),
    ("messages", {"mcap"}),
])
def test_a_layer_imports_with_what_it_must_not_use_blocked(layer, blocked):
    modules = sorted("cloth_lod_ros." + ".".join(p.relative_to(PACKAGE).with_suffix("").parts)
                     for p in (PACKAGE / layer).rglob("*.py") if p.name != "__init__.py")
    assert modules, f"no modules found in {layer}"
    proc = _import_blocked(modules, blocked)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == []


def test_the_blocker_does_block():
    """A module that needs a blocked package fails to import (else the test
    above could not fail)."""
    proc = _import_blocked(["cloth_lod_ros.messages.frames"], {"rclpy"})
    assert proc.returncode != 0 and "rclpy is blocked" in proc.stderr


def test_the_bag_files_are_written_and_read_without_rclpy(tmp_path):
    code = (f"{BLOCKER.format(blocked=['rclpy'], modules=['cloth_lod_ros.bag.rosbag'])}\n"
            "from cloth_lod_ros.bag.rosbag import BagReader, BagWriter\n"
            f"path = {str(tmp_path / 'bag')!r}\n"
            "with BagWriter(path) as w:\n"
            "    w.add_topic('/chatter', 'std_msgs/msg/String')\n"
            "    w.write('/chatter', bytes(4) + b'\\x03\\x00\\x00\\x00hi\\x00', 1)\n"
            "with BagReader(path) as r:\n"
            "    print([m.topic for m in r.messages()])\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=PACKAGE.parent,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "['/chatter']"
