"""The package's layers (docs/design.md §9): imports point down only.

sim < messages < bag < live < ros < tools.  The simulator must import without rclpy,
mcap or matplotlib installed; the MCAP code must not need rclpy to read or
write a bag; the message builders never touch mcap.
"""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "cloth_lod_ros"
LAYERS = ("sim", "messages", "bag", "live", "ros", "tools")
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
