"""Scene values checked one at a time: numbers, vectors and their bounds
(:mod:`~cloth_lod_ros.sim.scene.config` builds the sections from them).  Every
message names the field by its dotted path."""

from __future__ import annotations

import math
from typing import Any

from .bounded_yaml import HugeInteger as _HugeInteger
from .bounded_yaml import SceneError
from .bounded_yaml import shorten as _show

__all__ = ["MAX_INTEGER", "number", "vector", "check_bounds"]

#: Largest value of an integer field.
MAX_INTEGER = 2 ** 31 - 1


def number(value: Any, path: str, integer: bool = False) -> float:
    if isinstance(value, _HugeInteger):
        raise SceneError(f"field '{path}' is too large: {value!r}")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f"field '{path}' must be a number, got {_show(value)}")
    if isinstance(value, int):
        if integer and abs(value) > MAX_INTEGER:
            raise SceneError(f"field '{path}' is too large: {_show(value)} "
                             f"(at most {MAX_INTEGER})")
        try:
            float(value)
        except OverflowError:
            raise SceneError(f"field '{path}' is too large: {_show(value)} "
                             "(overflows a float)") from None
        return value if integer else float(value)
    if not math.isfinite(value):
        raise SceneError(f"field '{path}' must be finite, got {value!r}")
    if integer and not value.is_integer():
        raise SceneError(f"field '{path}' must be an integer, got {value!r}")
    if integer and abs(value) > MAX_INTEGER:
        raise SceneError(f"field '{path}' is too large: {value!r} (at most {MAX_INTEGER})")
    return int(value) if integer else float(value)


def vector(value: Any, path: str, length: int) -> tuple:
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise SceneError(f"field '{path}' must be a list of {length} numbers, "
                         f"got {_show(value)}")
    return tuple(number(v, f"{path}[{i}]") for i, v in enumerate(value))


def check_bounds(value, meta: dict, path: str) -> None:
    unit = f" {meta['unit']}" if meta["unit"] else ""
    items = value if isinstance(value, tuple) else (value,)
    for item in items:
        if meta["gt"] is not None and not item > meta["gt"]:
            raise SceneError(f"field '{path}' must be > {meta['gt']}{unit}, "
                             f"got {_show(value)}")
        if meta["ge"] is not None and not item >= meta["ge"]:
            raise SceneError(f"field '{path}' must be >= {meta['ge']}{unit}, "
                             f"got {_show(value)}")
        if meta["le"] is not None and not item <= meta["le"]:
            raise SceneError(f"field '{path}' must be <= {meta['le']}{unit}, "
                             f"got {_show(value)}")
