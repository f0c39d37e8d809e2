"""Scene configuration: typed dataclasses with SI units, loaded from YAML.

A scene file has the sections ``cloth``, ``material``, ``air``, ``pins``,
``simulation``, ``solver``, ``lod``, ``obstacles``, ``contact``, ``grasps`` and
``self_collision``,
each field with its unit in the dataclasses below (the README lists them all).
Loading is strict: a missing required field, an unknown field, a
value of the wrong type or out of range raises :class:`SceneError` whose message
names the field by its dotted path (``material.density``).

Scene files are input from anywhere, so loading is also bounded: a file of at
most :data:`MAX_SCENE_BYTES`, no YAML aliases (``*name``: scene files do not
need them, and nested aliases expand exponentially), nesting at most
:data:`MAX_NESTING` deep, numbers that fit their field, a finest mesh of at
most :data:`MAX_TRIANGLES` triangles, and a start within the cost budget of
:mod:`~cloth_lod_ros.sim.scene.budget` (start mesh, first step's work, counts of
pins, grasps, obstacles and waypoints).  Error messages quote values shortened.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import sys
from dataclasses import dataclass, field
from typing import Any

from . import budget as _budget
from .bounded_yaml import MAX_NESTING, MAX_SCENE_BYTES, SceneError
from .bounded_yaml import load_yaml as _load_yaml
from .bounded_yaml import shorten as _show
from .fabrics import PRESET_FIELDS, apply_preset
from .files import (apply_overrides, builtin_scene_names, find_scene_file, parse_override,
                    scenes_directory)
from .values import MAX_INTEGER, check_bounds as _check_bounds
from .values import number as _number, vector as _vector

__all__ = [
    "SceneError", "ClothConfig", "MaterialConfig", "AirConfig", "PinConfig", "LodConfig",
    "ObstacleConfig", "ContactConfig", "GraspConfig", "SelfCollisionConfig",
    "SimulationConfig", "SolverConfig", "SceneConfig",
    "load_scene", "scene_from_dict", "scene_to_dict", "apply_overrides", "clear_for_preset",
    "find_scene_file", "builtin_scene_names", "scenes_directory", "self_collision_on",
    "MAX_SCENE_BYTES", "MAX_NESTING", "MAX_TRIANGLES", "MAX_INTEGER",
]

#: Most triangles of the finest uniform mesh, 2 x blocks_u x blocks_v x 2^cloth.level
#: (2^21: base_blocks [1024, 1024] at level 0, a 1025 x 1025 particle grid).
MAX_TRIANGLES = 2 ** 21


def _spec(kind: str, unit: str = "", *, gt: float | None = None,
          ge: float | None = None, le: float | None = None,
          choices: tuple = (), doc: str = "", **kw):
    """Field metadata: value kind, unit, bounds and a one-line description."""
    return field(metadata=dict(kind=kind, unit=unit, gt=gt, ge=ge, le=le,
                               choices=choices, doc=doc), **kw)


@dataclass(frozen=True)
class ClothConfig:
    """Rectangular cloth and its 4-8 mesh."""

    width: float = _spec("float", "m", gt=0, doc="size along u")
    height: float = _spec("float", "m", gt=0, doc="size along v")
    base_blocks: tuple = _spec("int2", "", ge=1,
                               doc="square blocks along u and v of the level-0 mesh")
    level: int = _spec("int", "", ge=0, le=12, default=0,
                       doc="uniform bisection level (2 levels halve the edge length)")
    origin: tuple = _spec("vec3", "m", default=(0.0, 0.0, 1.0),
                          doc="world position of material point (0, 0)")
    u_axis: tuple = _spec("unit3", "", default=(1.0, 0.0, 0.0),
                          doc="world direction of increasing u at the start")
    v_axis: tuple = _spec("unit3", "", default=(0.0, 1.0, 0.0),
                          doc="world direction of increasing v at the start")


@dataclass(frozen=True)
class MaterialConfig:
    """Baraff–Witkin material in SI units (per unit rest area where it applies).
    ``preset`` names a fabric (:mod:`.fabrics`) whose density and stiffnesses fill the
    fields this mapping does not give."""

    preset: str = _spec("str", default="",
                        doc="fabric preset (docs/scenes.md); fields given here override it")
    density: float = _spec("float", "kg/m^2", gt=0, default=0.2, doc="areal density")
    stretch_stiffness: float = _spec("float", "N/m", ge=0, default=2000.0,
                                     doc="k_s of the u and v stretch conditions")
    shear_stiffness: float = _spec("float", "N/m", ge=0, default=200.0,
                                   doc="k_sh of the shear condition")
    bend_stiffness: float = _spec("float", "N*m", ge=0, default=2e-4,
                                  doc="k_b of the bend condition (bending rigidity)")
    stretch_damping: float = _spec("float", "s", ge=0, default=0.01,
                                   doc="Rayleigh coefficient: damping = this * stiffness")
    shear_damping: float = _spec("float", "s", ge=0, default=0.01, doc="as stretch_damping")
    bend_damping: float = _spec("float", "s", ge=0, default=0.1, doc="as stretch_damping")
    air_drag: float = _spec("float", "1/s", ge=0, default=0.0,
                            doc="isotropic drag force = -air_drag * mass * velocity (relative "
                                "to the ground, in every direction; the air section models "
                                "the air itself)")


@dataclass(frozen=True)
class AirConfig:
    """Air on each face along its normal (design §2): per triangle the force
    ``-1/2 density drag_coefficient A |v_n| v_n n`` (A its current area, n its unit
    normal, v_n = n . (mean velocity of its corners - wind)), a third to each corner.
    Sliding in its own plane or moving edge-on, the cloth feels none of it."""

    density: float = _spec("float", "kg/m^3", ge=0, le=1000, default=1.2,
                           doc="air density (1.2 at sea level and 20 C; 0: no face drag)")
    drag_coefficient: float = _spec("float", "", ge=0, le=100, default=1.2,
                                    doc="C_d on the face area (a thin square plate broadside "
                                        "to the flow: about 1.2)")
    wind: tuple = _spec("vec3", "m/s", ge=-1000, le=1000, default=(0.0, 0.0, 0.0),
                        doc="uniform wind velocity")


@dataclass(frozen=True)
class PinConfig:
    """A material point held at a target (by default where it starts)."""

    uv: tuple = _spec("vec2", "m", doc="material coordinates of the pinned point")
    name: str = _spec("str", default="", doc="label (defaults to pin<index>)")
    waypoints: tuple = _spec("waypoints", "s, m", default=(),
                             doc="[[t, x, y, z], ...] target path, linear between points")
    release_time: float | None = _spec("float?", "s", ge=0, default=None,
                                       doc="simulation time at which the pin lets go")
    radius: float = _spec("float", "m", ge=0, default=0.0,
                          doc="0: hold the one particle nearest uv (a point load, whose "
                              "sag and strain grow with refinement); > 0: hold every "
                              "particle within this (u, v) distance as a rigid patch")


@dataclass(frozen=True)
class ObstacleConfig:
    """An analytic rigid obstacle (only the fields of its ``type`` are used)."""

    type: str = _spec("str", choices=("plane", "sphere", "cylinder", "disc", "box"),
                      doc="shape")
    name: str = _spec("str", default="", doc="label (defaults to <type><index>)")
    centre: tuple = _spec("vec3", "m", default=(0.0, 0.0, 0.0),
                          doc="plane: a point on it; others: the centre")
    normal: tuple = _spec("unit3", "", default=(0.0, 0.0, 1.0), doc="plane: outward normal")
    radius: float = _spec("float", "m", gt=0, default=0.5, doc="sphere, cylinder, disc")
    axis: tuple = _spec("unit3", "", default=(0.0, 0.0, 1.0), doc="cylinder/disc axis")
    half_height: float = _spec("float", "m", gt=0, default=0.01,
                               doc="cylinder/disc: half its length along the axis")
    half_extents: tuple = _spec("vec3", "m", gt=0, default=(0.5, 0.5, 0.5), doc="box")
    orientation: tuple = _spec("quat", "", default=(0.0, 0.0, 0.0, 1.0),
                               doc="box: unit quaternion [x, y, z, w]")
    rounding: float = _spec("float", "m", ge=0, default=0.0,
                            doc="box: radius of its rounded edges")
    friction: float = _spec("float", "", ge=0, default=0.3, doc="Coulomb coefficient")
    waypoints: tuple = _spec("poses", "s, m", default=(),
                             doc="scripted pose path, [[t, x, y, z], ...] or [[t, x, y, z, "
                                 "qx, qy, qz, qw], ...]: the centre (a plane's point) and the "
                                 "orientation of the obstacle's frame (z = a plane's normal, "
                                 "a cylinder's axis); linear/slerp between points, held "
                                 "outside them; none: static unless driven live")
    max_speed: float = _spec("float", "m/s", gt=0, default=2.0,
                             doc="fastest the obstacle follows its target (script or live)")
    max_angular_speed: float = _spec("float", "rad/s", gt=0, default=6.0,
                                     doc="fastest the obstacle turns towards its target")


@dataclass(frozen=True)
class ContactConfig:
    thickness: float = _spec("float", "m", gt=0, default=0.004,
                             doc="particles keep this distance from obstacle surfaces")
    max_correction_speed: float = _spec("float", "m/s", gt=0, default=0.5,
                                        doc="fastest push out of a penetration")
    friction_rounds: int = _spec("int", "", ge=1, le=100, default=6,
                                 doc="most solves per contact solve while contacts start "
                                     "to slip (a slip front advances about one row of "
                                     "particles per solve; a sticking cloth pushed from "
                                     "one side needs about as many as it has rows)")


@dataclass(frozen=True)
class SelfCollisionConfig:
    """The cloth kept from passing through itself (design §3, "Self-collision")."""

    enabled: bool | str = _spec("auto_bool", default="auto",
                                doc="keep layers of the cloth apart: true, false, or auto "
                                    "(on where the thickness fits the finest mesh; the "
                                    "contact work runs only where layers come close)")
    thickness: float = _spec("float", "m", gt=0, default=0.004,
                             doc="distance kept between layers of the cloth")
    friction: float = _spec("float", "", ge=0, default=0.0,
                            doc="Coulomb coefficient between layers (0: frictionless)")
    max_resolves: int = _spec("int", "", ge=0, le=20, default=4,
                              doc="re-solves of a step in which two layers met")
    detail_level: int = _spec("int", "", ge=0, le=12, default=0,
                              doc="with LOD on, refine to at least this level where "
                                  "layers are within detail_distance (0: off)")
    detail_distance: float = _spec("float", "m", gt=0, default=0.012,
                                   doc="with LOD on, no merge (and detail_level) where "
                                       "another layer is this close")


@dataclass(frozen=True)
class GraspConfig:
    """A gripper holding the cloth at a material point (scripted or driven at run time)."""

    name: str = _spec("str", doc="label (topics use it)")
    uv: tuple = _spec("vec2", "m", doc="material point held")
    width: float = _spec("float", "m", ge=0, default=0.0,
                         doc="0: one particle; > 0: all particles within width/2 in (u, v)")
    tolerance: float = _spec("float", "m", gt=0, default=0.005,
                             doc="with LOD on, refine until a particle is this close to uv")
    max_speed: float = _spec("float", "m/s", gt=0, default=2.0,
                             doc="fastest the held point follows its target")
    max_angular_speed: float = _spec("float", "rad/s", gt=0, default=6.0,
                                     doc="fastest the grip turns towards its target")
    close_time: float | None = _spec("float?", "s", ge=0, default=None,
                                     doc="scripted closing time (None: closed at run time)")
    open_time: float | None = _spec("float?", "s", ge=0, default=None,
                                    doc="scripted opening time")
    waypoints: tuple = _spec("waypoints", "s, m", default=(),
                             doc="[[t, x, y, z], ...] scripted target path")


@dataclass(frozen=True)
class SimulationConfig:
    """Time integration (design §3; :mod:`~cloth_lod_ros.sim.integrate.step_control`)."""

    time_step: float = _spec("float", "s", ge=1e-6, le=1.0,
                             doc="frame period: the largest step h and the interval at "
                                 "which the cloth is published/recorded")
    duration: float = _spec("float", "s", ge=0, le=1e9, doc="simulated time of a run")
    gravity: tuple = _spec("vec3", "m/s^2", default=(0.0, 0.0, -9.81))
    integrator: str = _spec("str", choices=("sdirk2", "backward_euler", "baraff_witkin"),
                            default="sdirk2",
                            doc="sdirk2: L-stable 2-stage SDIRK, second order; "
                                "backward_euler: Newton-solved backward Euler; "
                                "baraff_witkin: the paper's linearised backward Euler "
                                "(one solve per step)")
    newton_iterations: int = _spec("int", "", ge=1, le=50, default=1,
                                   doc="most Newton iterations per implicit stage")
    newton_tolerance: float = _spec("float", "m", ge=0, default=1e-5,
                                    doc="stop Newton once a correction moves the particles "
                                        "by at most this (RMS)")
    error_tolerance: float | None = _spec(
        "float?", "m", ge=0, le=1.0, default=None,
        doc="largest estimated local position error per step (mass-weighted RMS); "
            "0: one step per frame; unset: 0.001 (0 with baraff_witkin, the paper's "
            "fixed step)")
    min_time_step: float = _spec("float", "s", ge=1e-6, le=1.0, default=1e-3,
                                 doc="smallest step the error control may take")


@dataclass(frozen=True)
class SolverConfig:
    method: str = _spec("str", choices=("auto", "pcg", "multigrid", "direct", "block_ldl",
                                          "cholmod", "superlu"),
                        default="auto",
                        doc="auto: direct on small systems, multigrid on large ones; pcg: "
                            "filtered block-Jacobi PCG (the paper's); multigrid: filtered CG "
                            "with a lattice V-cycle; direct: LDL^T (QDLDL), analysed once per "
                            "topology; block_ldl: LDL^T on 3x3 blocks compiled with numba; "
                            "cholmod: the same with CHOLMOD (optional extra, cvxopt); "
                            "superlu: SuperLU, re-analysed every solve (baseline)")
    tolerance: float = _spec("float", "", gt=0, le=0.5, default=1e-4,
                             doc="relative residual in the preconditioned norm")
    max_iterations: int = _spec("int", "", ge=1, default=2000)


@dataclass(frozen=True)
class LodConfig:
    """Adaptive level of detail (paper §5). With ``enabled``, ``cloth.level`` is the
    maximum level and the run starts at ``initial_level``."""

    enabled: bool = _spec("bool", default=False, doc="adapt the mesh at run time")
    initial_level: int = _spec("int", "", ge=0, le=12, default=0,
                               doc="uniform level the adaptive run starts from")
    refine_threshold: float = _spec("float", "m", gt=0, default=0.001,
                                    doc="refine an edge whose deviation d exceeds this")
    coarsen_threshold: float = _spec("float", "m", gt=0, default=0.00025,
                                     doc="merge only where every d is below this")
    max_hinge_rate: float = _spec("float", "rad/s", gt=0, default=0.5,
                                  doc="merge only where every |dtheta/dt| is below this")
    max_bend_force: float = _spec("float", "N", gt=0, default=1e-3,
                                  doc="merge only where every bend force is below this")
    max_merge_speed: float = _spec("float", "m/s", ge=0, default=0.03,
                                   doc="merge only where the energy the merge adds (elastic + "
                                       "kinetic + gravity) would move its diamond at most this "
                                       "fast: dE <= density x area x speed^2 / 2")
    min_lifetime: float = _spec("float", "s", ge=0, default=0.2,
                                doc="a triangle must exist this long before a merge removes it")
    check_interval: int = _spec("int", "steps", ge=1, default=4,
                                doc="evaluate the criterion every this many steps, refining "
                                    "what would cross the threshold before the next check "
                                    "(1: every step, the paper)")
    merge_interval: int = _spec("int", "checks", ge=1, default=1,
                                doc="simplify (merge) at every this many criterion checks; "
                                    "refinement is checked at every one")
    detail_level: int = _spec("int", "", ge=0, le=12, default=0,
                              doc="refine to at least this level near closed grasps and "
                                  "along contact borders (0: off)")
    detail_radius: float = _spec("float", "m", gt=0, default=0.08,
                                 doc="(u, v) distance from a grasp point that gets detail")
    criterion: str = _spec("str", choices=("curvature", "detail"), default="curvature",
                           doc="curvature: the paper's hinge deviation d; detail: the error "
                               "the coarse triangles make, from the jumps of the position "
                               "and velocity gradients across each edge and the hierarchical "
                               "detail of each split particle (design 4)")
    tolerance: float | None = _spec("float?", "", gt=0, default=None,
                                    doc="relative accuracy: refine_threshold = tolerance x "
                                        "h^2 / side (h the edge of the finest level, side the "
                                        "cloth's larger side), coarsen_threshold scaled with "
                                        "it; unset: the thresholds as given")
    uniform_share: float = _spec("float", "", gt=0, le=1, default=0.7,
                                 doc="criterion detail: once this share of the cloth's area "
                                     "is at the maximum level (or is to be), refine all of it "
                                     "there (a uniform mesh costs no more), and merge again "
                                     "only when that brings the share below 0.8 x this")
    velocity_horizon: float = _spec("float", "s", ge=0, default=0.1,
                                    doc="criterion detail: a velocity detail counts as the "
                                        "position detail it makes in this time")


@dataclass(frozen=True)
class SceneConfig:
    cloth: ClothConfig = _spec("section")
    simulation: SimulationConfig = _spec("section")
    name: str = _spec("str", default="scene")
    description: str = _spec("str", default="")
    material: MaterialConfig = _spec("section", default_factory=MaterialConfig)
    air: AirConfig = _spec("section", default_factory=AirConfig)
    pins: tuple = _spec("pins", default=())
    solver: SolverConfig = _spec("section", default_factory=SolverConfig)
    lod: LodConfig = _spec("section", default_factory=LodConfig)
    obstacles: tuple = _spec("obstacles", default=())
    contact: ContactConfig = _spec("section", default_factory=ContactConfig)
    grasps: tuple = _spec("grasps", default=())
    self_collision: SelfCollisionConfig = _spec("section",
                                                default_factory=SelfCollisionConfig)


_SECTION_TYPES = {"cloth": ClothConfig, "simulation": SimulationConfig,
                  "material": MaterialConfig, "air": AirConfig, "solver": SolverConfig,
                  "lod": LodConfig, "contact": ContactConfig,
                  "self_collision": SelfCollisionConfig}


def _unit_quaternion(vec: tuple, path: str) -> tuple:
    """A quaternion ``(x, y, z, w)`` normalised (left alone when already unit)."""
    norm = math.sqrt(sum(c * c for c in vec))
    if norm == 0.0 or not math.isfinite(norm):
        raise SceneError(f"field '{path}' must be a non-zero quaternion [x, y, z, w]")
    return tuple(c / norm for c in vec) if abs(norm - 1.0) > 1e-12 else vec


def _convert(value: Any, meta: dict, path: str, section_type=None):
    kind = meta["kind"]
    if kind == "section":
        if section_type is MaterialConfig:
            value = apply_preset(value, path)
        return _build(section_type, value, path)
    if kind == "float?" and value is None:
        return None
    if kind in ("float", "float?"):
        out = _number(value, path)
    elif kind == "int":
        out = _number(value, path, integer=True)
    elif kind == "int2":
        out = tuple(int(_number(v, f"{path}[{i}]", integer=True))
                    for i, v in enumerate(_vector(value, path, 2)))
    elif kind == "vec2":
        out = _vector(value, path, 2)
    elif kind == "vec3":
        out = _vector(value, path, 3)
    elif kind == "unit3":
        vec = _vector(value, path, 3)
        norm = math.sqrt(sum(c * c for c in vec))
        if norm == 0.0:
            raise SceneError(f"field '{path}' must be a non-zero direction")
        # Leave an already-unit vector alone: dividing by a norm that is 1 only
        # to rounding would change it, so scene_to_dict -> scene_from_dict
        # would not round-trip.
        out = vec if abs(norm - 1.0) <= 4 * sys.float_info.epsilon else tuple(
            c / norm for c in vec)
    elif kind == "auto_bool":
        if not isinstance(value, bool) and value != "auto":
            raise SceneError(f"field '{path}' must be true, false or auto, got {_show(value)}")
        return value
    elif kind == "bool":
        if not isinstance(value, bool):
            raise SceneError(f"field '{path}' must be true or false, got {_show(value)}")
        return value
    elif kind == "str":
        if not isinstance(value, str):
            raise SceneError(f"field '{path}' must be a string, got {_show(value)}")
        out = value
        if meta["choices"] and value not in meta["choices"]:
            raise SceneError(f"field '{path}' must be one of {list(meta['choices'])}, "
                             f"got {_show(value)}")
    elif kind == "quat":
        out = _unit_quaternion(_vector(value, path, 4), path)
    elif kind in ("obstacles", "grasps"):
        if not isinstance(value, (list, tuple)):
            raise SceneError(f"field '{path}' must be a list")
        cls = ObstacleConfig if kind == "obstacles" else GraspConfig
        out = tuple(_build(cls, p, f"{path}[{i}]") for i, p in enumerate(value))
        if kind == "obstacles":
            out = tuple(o if o.name else dataclasses.replace(o, name=f"{o.type}{i}")
                        for i, o in enumerate(out))
        names = [o.name for o in out]
        if len(set(names)) != len(names):
            raise SceneError(f"field '{path}' has duplicate names {_show(names)}")
    elif kind == "waypoints":
        if not isinstance(value, (list, tuple)):
            raise SceneError(f"field '{path}' must be a list of [t, x, y, z]")
        out = tuple(_vector(p, f"{path}[{i}]", 4) for i, p in enumerate(value))
        times = [p[0] for p in out]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise SceneError(f"field '{path}' times must increase strictly")
    elif kind == "poses":
        if not isinstance(value, (list, tuple)):
            raise SceneError(f"field '{path}' must be a list of [t, x, y, z] or "
                             "[t, x, y, z, qx, qy, qz, qw]")
        width = len(value[0]) if value and isinstance(value[0], (list, tuple)) else 4
        for i, p in enumerate(value):
            if not isinstance(p, (list, tuple)) or len(p) not in (4, 8) or len(p) != width:
                raise SceneError(f"field '{path}[{i}]' must be [t, x, y, z] or [t, x, y, z, "
                                 f"qx, qy, qz, qw] like the first row, got {_show(p)}")
        out = tuple(_vector(p, f"{path}[{i}]", width) for i, p in enumerate(value))
        if width == 8:
            out = tuple(p[:4] + _unit_quaternion(p[4:], f"{path}[{i}]")
                        for i, p in enumerate(out))
        times = [p[0] for p in out]
        if any(b <= a for a, b in zip(times, times[1:])):
            raise SceneError(f"field '{path}' times must increase strictly")
    elif kind == "pins":
        if not isinstance(value, (list, tuple)):
            raise SceneError(f"field '{path}' must be a list of pins")
        out = tuple(_build(PinConfig, p, f"{path}[{i}]") for i, p in enumerate(value))
        out = tuple(p if p.name else dataclasses.replace(p, name=f"pin{i}")
                    for i, p in enumerate(out))
        names = [p.name for p in out]
        if len(set(names)) != len(names):
            raise SceneError(f"field '{path}' has duplicate pin names {_show(names)}")
    else:  # pragma: no cover - programming error
        raise AssertionError(kind)
    _check_bounds(out, meta, path)
    return out


def _build(cls, data: Any, path: str):
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SceneError(f"field '{path}' must be a mapping, got {_show(data)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    prefix = f"{path}." if path else ""
    for key in data:
        if key not in fields:
            shown = key if isinstance(key, str) and len(key) <= 60 else _show(key)
            raise SceneError(f"unknown field '{prefix}{shown}' "
                             f"(expected one of: {', '.join(fields)})")
    kwargs = {}
    for name, f in fields.items():
        sub = f"{prefix}{name}"
        if name not in data:
            if (f.default is dataclasses.MISSING
                    and f.default_factory is dataclasses.MISSING):
                raise SceneError(f"missing field '{sub}'")
            continue
        kwargs[name] = _convert(data[name], f.metadata, sub, _SECTION_TYPES.get(name))
    return cls(**kwargs)


def _layer_gap(cloth: ClothConfig) -> float:
    """Distance (m) from a particle of the finest flat 4-8 mesh to the nearest
    particle that is not a corner of a triangle it is on: leg/sqrt(2), leg =
    block side / 2^(level/2)."""
    side = cloth.width / cloth.base_blocks[0]
    return side / 2 ** (cloth.level / 2) / math.sqrt(2.0)


def _thickness_fits(thickness: float, gap: float) -> bool:
    """Whether the contact band (2 x thickness) fits between neighbouring
    particles ``gap`` m apart, or the flat cloth would be in contact with itself."""
    return 2.0 * thickness < 0.9 * gap


def self_collision_on(scene: "SceneConfig") -> bool:
    """Whether the scene runs self-collision: ``enabled: true``, or ``auto``
    where its thickness fits the finest mesh (:func:`_thickness_fits`)."""
    own = scene.self_collision
    if own.enabled == "auto":
        return _thickness_fits(own.thickness, _layer_gap(scene.cloth))
    return bool(own.enabled)


def scene_from_dict(data: Any) -> SceneConfig:
    """Validate a parsed scene mapping and build a :class:`SceneConfig`.

    Raises:
        SceneError: a field is invalid, or the scene exceeds the cost budget
            (:func:`~cloth_lod_ros.sim.scene.budget.check`).
    """
    _budget.check_counts(data)          # before converting thousands of entries
    scene = _build(SceneConfig, data, "")
    cloth = scene.cloth
    triangles = 2 * cloth.base_blocks[0] * cloth.base_blocks[1] * 2 ** cloth.level
    if triangles > MAX_TRIANGLES:
        raise SceneError(
            f"fields 'cloth.base_blocks' {list(cloth.base_blocks)} and 'cloth.level' "
            f"{cloth.level} ask for a finest mesh of {triangles:,} triangles "
            f"(2 x blocks_u x blocks_v x 2^level); the limit is {MAX_TRIANGLES:,}")
    side_u = cloth.width / cloth.base_blocks[0]
    side_v = cloth.height / cloth.base_blocks[1]
    if not math.isclose(side_u, side_v, rel_tol=1e-12):
        raise SceneError(
            f"field 'cloth.base_blocks' must make square blocks: width/blocks_u = "
            f"{side_u} m but height/blocks_v = {side_v} m")
    dot = sum(a * b for a, b in zip(cloth.u_axis, cloth.v_axis))
    if abs(dot) > 1e-9:
        raise SceneError("field 'cloth.v_axis' must be perpendicular to 'cloth.u_axis'")
    lod = scene.lod
    if lod.coarsen_threshold >= lod.refine_threshold:
        raise SceneError(f"field 'lod.coarsen_threshold' ({lod.coarsen_threshold} m) must be "
                         f"below 'lod.refine_threshold' ({lod.refine_threshold} m)")
    if lod.enabled and lod.initial_level > cloth.level:
        raise SceneError(f"field 'lod.initial_level' ({lod.initial_level}) must not exceed "
                         f"'cloth.level' ({cloth.level}), the maximum level with LOD on")
    own = scene.self_collision
    if own.enabled is True:
        gap = _layer_gap(cloth)
        if not _thickness_fits(own.thickness, gap):
            raise SceneError(f"field 'self_collision.thickness' ({own.thickness} m) must be "
                             f"below {0.45 * gap:.3g} m: twice it must fit between "
                             f"neighbouring layers of the finest mesh ({gap:.3g} m apart)")
        if own.detail_distance < own.thickness:
            raise SceneError("field 'self_collision.detail_distance' must be at least "
                             "'self_collision.thickness'")
    for i, obstacle in enumerate(scene.obstacles):
        if obstacle.type == "box" and obstacle.rounding >= min(obstacle.half_extents):
            raise SceneError(f"field 'obstacles[{i}].rounding' must be below the smallest "
                             "half extent")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", obstacle.name):
            raise SceneError(f"field 'obstacles[{i}].name' = {_show(obstacle.name)} must be "
                             "letters, digits and underscores, not starting with a digit "
                             "(it names ROS topics)")
    for i, grasp in enumerate(scene.grasps):
        u, v = grasp.uv
        if not (0.0 <= u <= cloth.width and 0.0 <= v <= cloth.height):
            raise SceneError(f"field 'grasps[{i}].uv' = {grasp.uv} lies outside the "
                             f"{cloth.width} x {cloth.height} m cloth")
        if (grasp.close_time is not None and grasp.open_time is not None
                and grasp.open_time <= grasp.close_time):
            raise SceneError(f"field 'grasps[{i}].open_time' must come after close_time")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", grasp.name):  # ASCII: str.isalnum takes "é"
            raise SceneError(f"field 'grasps[{i}].name' = {_show(grasp.name)} must be letters, "
                             "digits and underscores, not starting with a digit (it names ROS topics)")
    for i, pin in enumerate(scene.pins):
        u, v = pin.uv
        if not (0.0 <= u <= cloth.width and 0.0 <= v <= cloth.height):
            raise SceneError(f"field 'pins[{i}].uv' = {pin.uv} lies outside the "
                             f"{cloth.width} x {cloth.height} m cloth")
        for j, other in enumerate(scene.pins[:i]):
            reach = pin.radius + other.radius
            if reach > 0 and math.dist(pin.uv, other.uv) <= reach:
                raise SceneError(f"field 'pins[{i}].radius': its patch overlaps that of "
                                 f"pins[{j}] (centres {math.dist(pin.uv, other.uv):.4g} m "
                                 f"apart, radii {other.radius} + {pin.radius} m)")
    _budget.check(scene)
    return scene


def scene_to_dict(scene: SceneConfig) -> dict:
    """Plain mapping (lists, floats) that :func:`scene_from_dict` accepts back."""
    def plain(value):
        if dataclasses.is_dataclass(value):
            return {f.name: plain(getattr(value, f.name))
                    for f in dataclasses.fields(value)}
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        return value
    return plain(scene)


def clear_for_preset(data: dict, keys) -> dict:
    """``data`` (a raw scene mapping) ready for the overrides ``keys`` (dotted paths):
    when they choose ``material.preset``, without the scene's own values of the fields
    a preset fills - an override's preset replaces them, and the overrides that set
    those fields still apply on top, in any order."""
    if "material.preset" not in keys or not isinstance(data.get("material"), dict):
        return data
    out = dict(data)
    out["material"] = {k: v for k, v in data["material"].items() if k not in PRESET_FIELDS}
    return out


def load_scene(scene: str | os.PathLike,
               overrides: list[str] | dict | None = None) -> SceneConfig:
    """Load a scene by built-in name or path, apply overrides, validate.

    Raises:
        SceneError: unreadable YAML, or any field missing, unknown, of the wrong
            type or out of range (the message names it).
    """
    path = find_scene_file(scene)
    try:
        with open(path, "rb") as f:
            text = f.read(MAX_SCENE_BYTES + 1)       # never more than the limit
    except OSError as exc:
        raise SceneError(f"{path}: cannot read ({exc})") from exc
    data = _load_yaml(text, str(path))
    if not isinstance(data, dict):
        raise SceneError(f"{path}: a scene file must be a mapping of sections")
    if overrides:
        items = list(overrides.items()) if isinstance(overrides, dict) else [
            parse_override(o) for o in overrides]
        data = clear_for_preset(data, [key for key, _ in items])
        for key, value in items:
            data = apply_overrides(data, {key: value})
    data.setdefault("name", path.stem)
    return scene_from_dict(data)
