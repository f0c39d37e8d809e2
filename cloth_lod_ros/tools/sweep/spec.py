"""Sweep files: what to vary, and the runs they expand to (``cloth-lod sweep``).

A sweep file (YAML) names a base scene and the scene fields to vary; every
field is a ``cloth-lod run --set`` key (a dotted path, applied by the scene
loader's own :func:`~cloth_lod_ros.sim.scene.config.apply_overrides`), or an item of
a list section addressed by index or name, ``grasps[left].waypoints``,
``obstacles[0].centre``, ``pins[top_left].uv`` (the whole list, with that one
field changed, is set through the same function).  ``docs/sweeps.md`` is the
reference; in short::

    scene: hang_two_corners          # built-in name, or a path (relative to this file)
    duration: 0.5                    # s simulated by every run (default: the scene's)
    set: {cloth.level: 4}            # fixed overrides of every run
    grid:                            # every combination ...
      material.stretch_stiffness: [500, 2000]
    list:                            # ... and these runs ...
      - {material.density: 0.1}
      - {material.density: 0.3, material.stretch_stiffness: 800}
    random:                          # ... and random draws
      samples: 4
      seed: 7
      parameters:
        material.bend_stiffness: {log_uniform: [1.0e-5, 1.0e-3]}
    repeats: 1
    keep: [statistics, state]        # also: frames, bag
    reference: {name: fine, set: {cloth.level: 6, lod.enabled: false}}

``combine: union`` (the default) runs the grid's runs, then the list's, then
the random draws; ``combine: product`` runs every combination of one of each
(a grid of LOD settings for each random material, say).

Each run's scene is resolved here, on the machine that starts the sweep: the
run carries the whole validated scene as a plain mapping
(:func:`~cloth_lod_ros.sim.scene.config.scene_to_dict`), so workers need no scene
files, and the table row that holds it reproduces the run.  A run whose
parameters the scene loader refuses is kept, with the loader's message, and
recorded as failed without being sent anywhere.

Run ids are the first 16 hex digits of the SHA-256 of the run's identity (the
base scene with the fixed overrides, the varied parameters, the repeat, the
random seed and sample index) in canonical JSON, so the same sweep file always
names the same runs and ``--resume`` recognises them.  Random draw ``i`` uses
``numpy.random.default_rng([seed, i])``: raising ``samples`` keeps the draws
already made (and their ids).
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...sim import SceneError, load_scene
from ...sim.scene.config import (apply_overrides, clear_for_preset, find_scene_file,
                                 parse_override, scene_from_dict, scene_to_dict)
from ..reference import ConvergedReference

__all__ = ["SweepError", "SweepSpec", "PlannedRun", "load_spec", "plan_runs", "run_id_of",
           "KEEP_CHOICES", "DISTRIBUTIONS", "resolve_scene", "scene_yaml"]

KEEP_CHOICES = ("statistics", "state", "frames", "bag")
DISTRIBUTIONS = ("uniform", "log_uniform", "normal", "choice")
TOP_LEVEL = ("scene", "duration", "set", "grid", "list", "random", "combine", "repeats",
             "keep", "frames", "grid_points", "bag_rate", "reference", "description")
COMBINE = ("union", "product")
#: ``section[index or name].rest.of.path``
INDEXED = re.compile(r"^([A-Za-z_]\w*)\[([^\]]+)\](?:\.(.+))?$")


class SweepError(ValueError):
    """A sweep file that cannot be used (the message names the field)."""


@dataclass
class SweepSpec:
    """A parsed sweep file (module docstring; units as in the scene files).

    Attributes:
        path: the sweep file.
        scene: the base scene as given; ``scene_source`` the file it resolved to.
        base: the base scene with ``duration`` and ``set`` applied, as a plain
            mapping (:func:`scene_to_dict`).
        grid, items, random: the varied parameters (``items`` is the file's ``list``).
        combine: ``"union"`` or ``"product"`` of the three (module docstring).
        repeats: runs of each parameter set.
        keep: per-run outputs (:data:`KEEP_CHOICES`).
        frames: sampled frames per run with ``keep: [frames]``.
        grid_points: material sample points per side (frames, reference errors).
        bag_rate: frames per simulated second recorded with ``keep: [bag]``.
        reference: ``{"name", "overrides"}`` or None.
    """

    path: Path
    scene: str
    scene_source: str
    base: dict
    fixed: dict
    grid: dict = field(default_factory=dict)
    items: list = field(default_factory=list)
    random: dict | None = None
    combine: str = "union"
    repeats: int = 1
    keep: tuple = ("statistics",)
    frames: int = 10
    grid_points: int = 11
    bag_rate: float = 30.0
    reference: dict | None = None
    description: str = ""

    @property
    def parameter_keys(self) -> list[str]:
        """Every varied key, in file order (grid, list, random): the table's
        parameter columns."""
        keys = list(self.grid)
        for item in self.items:
            keys += [k for k in item if k not in keys]
        if self.random:
            keys += [k for k in self.random["parameters"] if k not in keys]
        return keys


@dataclass
class PlannedRun:
    """One run of a sweep, resolved on the client.

    Attributes:
        run_id: 16 hex digits (module docstring).
        kind: ``"run"`` or ``"reference"``.
        index: position in the sweep (references: after the runs).
        params: the varied parameters (key -> value as in the file or drawn).
        repeat, sample, seed: repeat index; random draw index and sweep seed
            (None without ``random``).
        scene: the resolved scene mapping, or None if the parameters are refused.
        error: the refusal (``"SceneError: ..."``), else None.
        reference_id: the id of this run's reference run (None without one).
    """

    run_id: str
    kind: str
    index: int
    params: dict
    repeat: int = 0
    sample: int | None = None
    seed: int | None = None
    scene: dict | None = None
    error: str | None = None
    reference_id: str | None = None


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=_plain)


def _plain(value: Any):
    """JSON for numpy scalars and arrays (drawn values)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")


def run_id_of(identity: dict) -> str:
    """The 16-hex-digit id of a run: SHA-256 of its identity in canonical JSON."""
    return hashlib.sha256(_canonical(identity).encode()).hexdigest()[:16]


def scene_yaml(scene: dict) -> str:
    """A resolved scene mapping as a scene file (``cloth-lod run FILE`` loads it;
    floats are written as ``repr``, so they read back bit for bit)."""
    import yaml
    return yaml.safe_dump(scene, sort_keys=False, default_flow_style=None, width=100)


def _set_item(data: dict, key: str, value: Any) -> dict:
    """``section[i].path=value`` on a raw scene mapping: the list ``section``
    with item ``i`` (an index or the item's ``name``) changed, set whole by
    :func:`apply_overrides`."""
    m = INDEXED.match(key)
    section, which, rest = m.group(1), m.group(2).strip(), m.group(3)
    items = data.get(section)
    if not isinstance(items, list):
        raise SceneError(f"cannot set '{key}': '{section}' is not a list in the scene")
    items = copy.deepcopy(items)
    if re.fullmatch(r"-?\d+", which):
        index = int(which)
        if not -len(items) <= index < len(items):
            raise SceneError(f"cannot set '{key}': '{section}' has {len(items)} item(s)")
    else:
        names = [item.get("name") if isinstance(item, dict) else None for item in items]
        if which not in names:
            raise SceneError(f"cannot set '{key}': no item named {which!r} in '{section}' "
                             f"(names: {', '.join(str(n) for n in names)})")
        index = names.index(which)
    if rest is None:
        items[index] = value
    else:
        if not isinstance(items[index], dict):
            raise SceneError(f"cannot set '{key}': '{section}[{which}]' is not a mapping")
        items[index] = apply_overrides(items[index], {rest: value})
    return apply_overrides(data, {section: items})


def resolve_scene(base: dict, params: dict) -> dict:
    """The scene ``base`` with ``params`` applied (in order), validated by the
    scene loader, as a plain mapping.

    Raises:
        SceneError: a key or value the loader refuses (its message).
    """
    data = clear_for_preset(base, list(params))
    for key, value in params.items():
        value = json.loads(_canonical(value))       # numpy draws -> plain numbers
        data = _set_item(data, key, value) if INDEXED.match(key) else apply_overrides(
            data, {key: value})
    return scene_to_dict(scene_from_dict(data))


def _mapping(value: Any, where: str) -> dict:
    if value is None:
        return {}
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        try:
            return dict(parse_override(v) for v in value)      # ["key=value", ...]
        except SceneError as exc:
            raise SweepError(f"{where}: {exc}") from None
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise SweepError(f"'{where}' must be a mapping of scene keys to values")
    return dict(value)


def _positive_int(raw: dict, key: str, default: int, minimum: int = 1) -> int:
    value = raw.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise SweepError(f"'{key}' must be a whole number >= {minimum}, got {value!r}")
    return value


def _check_distribution(key: str, spec: Any) -> None:
    where = f"random.parameters.{key}"
    if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in DISTRIBUTIONS:
        raise SweepError(f"'{where}' must be one of "
                         + ", ".join(f"{{{d}: ...}}" for d in DISTRIBUTIONS))
    (kind, args), = spec.items()
    if kind == "choice":
        if not isinstance(args, list) or not args:
            raise SweepError(f"'{where}': choice needs a non-empty list of values")
        return
    if not isinstance(args, list) or len(args) != 2:
        raise SweepError(f"'{where}': {kind} needs [a, b] (numbers or equal-length lists)")
    try:
        a, b = np.asarray(args[0], dtype=float), np.asarray(args[1], dtype=float)
        np.broadcast(a, b)
    except (TypeError, ValueError):
        raise SweepError(f"'{where}': {kind} needs [a, b] of numbers, got {args!r}") from None
    if kind == "log_uniform" and (np.any(a <= 0) or np.any(b <= 0)):
        raise SweepError(f"'{where}': log_uniform bounds must be positive")
    if kind == "normal" and np.any(b < 0):
        raise SweepError(f"'{where}': normal needs [mean, standard deviation >= 0]")


def _draw(rng: np.random.Generator, spec: dict):
    """One value of ``{kind: args}`` (plain floats, lists for vector bounds)."""
    (kind, args), = spec.items()
    if kind == "choice":
        return copy.deepcopy(args[int(rng.integers(len(args)))])
    a, b = np.asarray(args[0], dtype=float), np.asarray(args[1], dtype=float)
    shape = np.broadcast(a, b).shape
    if kind == "uniform":
        value = rng.uniform(a, b, size=shape)
    elif kind == "log_uniform":
        value = np.exp(rng.uniform(np.log(a), np.log(b), size=shape))
    else:
        value = rng.normal(a, b, size=shape)
    return value.tolist() if shape else float(value)


def load_spec(path: str | Path) -> SweepSpec:
    """Read and check a sweep file; resolve its base scene.

    Raises:
        SweepError: a malformed sweep file (the field is named).
        SceneError: the base scene or its fixed overrides are refused.
    """
    import yaml
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise SweepError(f"cannot read the sweep file {path}: {exc}") from None
    except yaml.YAMLError as exc:
        raise SweepError(f"{path}: not YAML: {exc}") from None
    if not isinstance(raw, dict):
        raise SweepError(f"{path}: a sweep file is a mapping (scene, grid, ...)")
    unknown = sorted(set(raw) - set(TOP_LEVEL))
    if unknown:
        raise SweepError(f"{path}: unknown field(s) {', '.join(unknown)}; known: "
                         + ", ".join(TOP_LEVEL))
    if not isinstance(raw.get("scene"), str):
        raise SweepError(f"{path}: 'scene' (a built-in name or a scene file path) is required")
    scene = raw["scene"]
    local = (path.parent / scene)
    source = str(local.resolve()) if local.is_file() else str(find_scene_file(scene))
    fixed = _mapping(raw.get("set"), "set")
    if raw.get("duration") is not None:
        duration = raw["duration"]
        if isinstance(duration, bool) or not isinstance(duration, (int, float)) or not (
                math.isfinite(duration) and duration >= 0):
            raise SweepError(f"'duration' must be a number of seconds >= 0, got {duration!r}")
        fixed = {"simulation.duration": float(duration), **fixed}
    base_scene = load_scene(source)                 # the name a file path gives its scene
    base = scene_to_dict(base_scene)
    try:
        base = resolve_scene(base, fixed)
    except SceneError as exc:
        raise SceneError(f"the sweep's fixed overrides: {exc}") from None
    grid = _mapping(raw.get("grid"), "grid")
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise SweepError(f"'grid.{key}' must be a non-empty list of values")
    items = raw.get("list") or []
    if not isinstance(items, list):
        raise SweepError("'list' must be a list of mappings (one per run)")
    items = [_mapping(item, f"list[{i}]") for i, item in enumerate(items)]
    random = raw.get("random")
    if random is not None:
        if not isinstance(random, dict) or set(random) - {"samples", "seed", "parameters"}:
            raise SweepError("'random' has 'samples', 'seed' and 'parameters' only")
        samples = _positive_int(random, "samples", 1)
        seed = random.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise SweepError(f"'random.seed' must be a whole number >= 0, got {seed!r}")
        parameters = _mapping(random.get("parameters"), "random.parameters")
        if not parameters:
            raise SweepError("'random.parameters' is empty")
        for key, dist in parameters.items():
            _check_distribution(key, dist)
        random = dict(samples=samples, seed=seed, parameters=parameters)
    combine = raw.get("combine", "union")
    if combine not in COMBINE:
        raise SweepError(f"'combine' is one of {', '.join(COMBINE)}, got {combine!r}")
    sources = [set(grid), set().union(*items)] + (
        [set(random["parameters"])] if random else [])
    for a, b in itertools.combinations(sources, 2):
        if combine == "product" and a & b:
            raise SweepError(f"key(s) {', '.join(sorted(a & b))} varied in two places "
                             "(grid, list, random) with combine: product: vary each key "
                             "in one")
    keep = raw.get("keep", ["statistics"])
    keep = [keep] if isinstance(keep, str) else keep
    if not isinstance(keep, list) or any(k not in KEEP_CHOICES for k in keep):
        raise SweepError(f"'keep' must list some of {', '.join(KEEP_CHOICES)}, got {keep!r}")
    bag_rate = raw.get("bag_rate", 30.0)
    if isinstance(bag_rate, bool) or not isinstance(bag_rate, (int, float)) or not (
            bag_rate > 0 and math.isfinite(bag_rate)):
        raise SweepError("'bag_rate' must be a positive number of frames per second")
    spec = SweepSpec(path=path, scene=scene, scene_source=source, base=base, fixed=fixed,
                     grid=grid, items=items, random=random, combine=combine,
                     repeats=_positive_int(raw, "repeats", 1),
                     keep=tuple(dict.fromkeys(keep)), frames=_positive_int(raw, "frames", 10, 2),
                     grid_points=_positive_int(raw, "grid_points", 11, 2),
                     bag_rate=float(bag_rate), reference=_reference(raw.get("reference")),
                     description=str(raw.get("description", "")))
    return spec


def _reference(raw: Any) -> dict | None:
    """``reference``: ``{name, set: {...}}`` (each run with these overrides on
    top) or ``{name, converged: {level, divisor}}`` (the converged reference of
    :mod:`cloth_lod_ros.tools.reference` at the run's own frame period)."""
    if raw is None:
        return None
    if not isinstance(raw, dict) or set(raw) - {"name", "set", "converged"} or (
            ("set" in raw) == ("converged" in raw)):
        raise SweepError("'reference' is {name: NAME, set: {key: value, ...}} or "
                         "{name: NAME, converged: {level: L, divisor: 8}}")
    name = str(raw.get("name", "reference"))
    if "set" in raw:
        return dict(name=name, overrides=_mapping(raw["set"], "reference.set"), converged=None)
    conv = raw["converged"] or {}
    if not isinstance(conv, dict) or set(conv) - {"level", "divisor"} or "level" not in conv:
        raise SweepError("'reference.converged' is {level: L, divisor: K (default 8)}")
    try:
        ConvergedReference(int(conv["level"]), 1.0, conv.get("divisor", 8))
    except (TypeError, ValueError) as exc:
        raise SweepError(f"'reference.converged': {exc}") from None
    return dict(name=name, overrides={}, converged=dict(level=int(conv["level"]),
                                                         divisor=conv.get("divisor", 8)))


def _reference_params(spec: SweepSpec, params: dict, scene: dict) -> dict:
    ref = spec.reference
    if ref["converged"] is None:
        return {**params, **ref["overrides"]}
    conv = ConvergedReference(ref["converged"]["level"], scene["simulation"]["time_step"],
                              ref["converged"]["divisor"])
    return {**params, **dict(parse_override(o) for o in conv.overrides())}


def _parameter_sets(spec: SweepSpec) -> list[tuple[dict, int | None]]:
    """``(params, random sample index or None)`` of every parameter set, in order."""
    grid_keys = list(spec.grid)
    grid = [(dict(zip(grid_keys, values)), None)
            for values in itertools.product(*(spec.grid[k] for k in grid_keys))] \
        if spec.grid else []
    items = [(dict(item), None) for item in spec.items]
    draws = []
    if spec.random:
        for i in range(spec.random["samples"]):
            rng = np.random.default_rng([spec.random["seed"], i])
            draws.append(({k: _draw(rng, d) for k, d in spec.random["parameters"].items()},
                          i))
    parts = [part for part in (grid, items, draws) if part]
    if spec.combine == "union":
        return [entry for part in parts for entry in part] or [({}, None)]
    out = []
    for combination in itertools.product(*parts):
        params, sample = {}, None
        for p, s in combination:
            params.update(p)
            sample = s if s is not None else sample
        out.append((params, sample))
    return out or [({}, None)]


def plan_runs(spec: SweepSpec) -> list[PlannedRun]:
    """Every run of the sweep in order (the parameter sets, each ``repeats``
    times), then the reference runs they need (one per distinct reference
    scene).  A parameter set given twice (the same values in the grid and the
    list, say) is run once."""
    runs: list[PlannedRun] = []
    seen: set[str] = set()
    references: dict[str, PlannedRun] = {}
    for params, sample in _parameter_sets(spec):
        seed = spec.random["seed"] if spec.random and sample is not None else None
        try:
            scene, error = resolve_scene(spec.base, params), None
        except SceneError as exc:
            scene, error = None, f"SceneError: {exc}"
        ref_id = None
        if spec.reference and scene is not None:
            ref_params = _reference_params(spec, params, scene)
            try:
                ref_scene, ref_error = resolve_scene(spec.base, ref_params), None
            except SceneError as exc:
                ref_scene, ref_error = None, f"SceneError: {exc}"
            # One reference per distinct scene; the lod section of a scene with
            # LOD off does not count (a sweep of LOD settings shares one reference).
            same = (dict(ref_scene, lod=None) if ref_scene and not ref_scene["lod"]["enabled"]
                    else ref_scene)
            ref_id = run_id_of(dict(kind="reference", scene=same) if ref_scene else
                               dict(kind="reference", base=spec.base, params=ref_params))
            if ref_id not in references:
                references[ref_id] = PlannedRun(ref_id, "reference", -1, ref_params,
                                                scene=ref_scene, error=ref_error)
        for repeat in range(spec.repeats):
            identity = dict(kind="run", base=spec.base, params=params, repeat=repeat,
                            seed=seed, sample=sample)
            run_id = run_id_of(identity)
            if run_id in seen:
                continue
            seen.add(run_id)
            runs.append(PlannedRun(run_id, "run", len(runs), params, repeat, sample, seed,
                                   scene, error, ref_id))
    for i, ref in enumerate(references.values()):
        ref.index = len(runs) + i
    return runs + list(references.values())
