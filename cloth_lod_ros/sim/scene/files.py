"""Scene files: where built-in scenes live, how a name or path resolves to a
file, and ``key=value`` overrides of a raw scene mapping (re-exported by
:mod:`~cloth_lod_ros.sim.scene.config`).
"""

from __future__ import annotations

import copy
import os
import sys
from pathlib import Path

from .bounded_yaml import SceneError
from .bounded_yaml import load_yaml as _load_yaml
from .bounded_yaml import shorten as _show

__all__ = ["apply_overrides", "parse_override", "scenes_directory", "builtin_scene_names",
           "find_scene_file"]


def apply_overrides(data: dict, overrides: list[str] | dict) -> dict:
    """Return a copy of a raw scene mapping with ``key=value`` overrides set.

    Keys are dotted paths (``material.density``, ``cloth.base_blocks``); values
    are parsed as YAML (``0.3``, ``[8, 8]``, ``false``).  The result still goes
    through :func:`scene_from_dict`, so a bad value is refused there.
    """
    out = copy.deepcopy(data)
    items = overrides.items() if isinstance(overrides, dict) else (
        parse_override(o) for o in overrides)
    for key, value in items:
        parts = key.split(".")
        node = out
        for i, part in enumerate(parts[:-1]):
            child = node.get(part) if isinstance(node, dict) else None
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise SceneError(f"cannot set '{key}': '{'.'.join(parts[:i + 1])}' "
                                 "is not a section")
            node = child
        node[parts[-1]] = value
    return out


def parse_override(text: str):
    """``"key=value"`` -> ``(key, value)``, the value parsed as YAML (bounded as scene files are)."""
    if "=" not in text:
        raise SceneError(f"override {_show(text)} must look like key=value")
    key, raw = text.split("=", 1)
    key = key.strip()
    if not key:
        raise SceneError(f"override {_show(text)} has an empty key")
    return key, _load_yaml(raw, f"override {_show(text)}")


def scenes_directory() -> Path:
    """Directory of the built-in scenes (installed share/ or the source tree)."""
    # A source checkout first (repository root = three levels above this file):
    # the scenes that belong to the code being run, not an older installed copy.
    candidates = [Path(__file__).resolve().parents[2] / "config" / "scenes"]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "cloth_lod_ros" / "config" / "scenes")
    candidates.append(Path(sys.prefix) / "share" / "cloth_lod_ros" / "config" / "scenes")
    for path in candidates:
        if path.is_dir():
            return path
    raise SceneError("built-in scene directory not found (is the package installed?)")


def builtin_scene_names() -> list[str]:
    return sorted(p.stem for p in scenes_directory().glob("*.yaml"))


def _not_a_scene_file(path: Path) -> SceneError:
    if path.is_dir():
        return SceneError(f"scene path {_show(str(path))} is a directory, not a scene file")
    if path.exists():
        return SceneError(f"scene path {_show(str(path))} is not a regular file")
    return SceneError(f"scene file {_show(str(path))} does not exist")


def find_scene_file(scene: str | os.PathLike) -> Path:
    """Resolve a built-in scene name or a YAML file path.

    A path to an existing file wins; ``name`` (no ``.yaml``/``.yml``, no
    directory part) is otherwise a built-in scene, even if a directory of that
    name exists here.
    """
    path = Path(scene)
    if path.is_file():
        return path
    text = str(scene)
    if path.suffix in (".yaml", ".yml") or os.sep in text or (os.altsep and os.altsep in text):
        raise _not_a_scene_file(path)
    candidate = scenes_directory() / f"{scene}.yaml"
    if candidate.is_file():
        return candidate
    if path.exists():
        raise _not_a_scene_file(path)
    raise SceneError(f"unknown scene {_show(text)}; built-in scenes: "
                     f"{', '.join(builtin_scene_names())}")
