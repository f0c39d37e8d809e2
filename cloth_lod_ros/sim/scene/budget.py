"""What a scene costs before anything is built, and the limits it must keep (design §10).

A scene file is input from anywhere; within the per-field ranges a file of a few
lines could still ask for a start that takes minutes and gigabytes (a uniform
level-12 mesh on 4 x 4 blocks: 131,072 triangles, 38 s and 646 MB before the first
frame).  :func:`estimate` reads the validated scene only (no mesh, no numpy) and
:func:`check` refuses what exceeds the limits below with one line naming the fields.

The estimate, for the mesh the simulator builds at the start (``ClothSim.__init__``):

* LOD off: the uniform mesh, ``T = 2 bu bv 2^level`` triangles.
* LOD on: the uniform ``lod.initial_level`` mesh, plus per pin of radius r > 0 its
  patch refined to the maximum level, bounded by the disc of radius ``r + 2 leg``
  (leg: the finest triangle's leg) at the finest triangle area, plus per grasp the
  triangles that bring a particle within ``tolerance`` of its point (a chain of at
  most ``4 (level + 1)``) and, with ``lod.detail_level``, its ``detail_radius`` disc
  at that level.  Never more than the finest uniform mesh.  (``test_budget.py``
  checks that the built mesh never exceeds it.)
* Particles: about half the triangles plus the boundary, ``T/2 + sqrt(2 T) + 1``.
* Memory: :data:`BYTES_PER_TRIANGLE` per triangle over the process's own
  (imports, compiled kernels: about 200 MB), the slope of peak RSS between
  uniform level-8, 10 and 11 meshes with the default solver.
* The work of the first step, in triangle-solves: triangles x the linear solves one
  step may take (2 stages with ``sdirk2``, x ``newton_iterations``, x
  ``contact.friction_rounds`` with obstacles, x ``1 + self_collision.max_resolves``
  with self-collision).  One solve of the default solver costs about 15 us of CPU
  per triangle.

Counts are limited too: each pin, grasp and obstacle adds per-step work and (in the
node) topics and services, and every waypoint row is a value to read and check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .bounded_yaml import SceneError

__all__ = ["SceneCost", "estimate", "check", "check_counts", "MAX_START_TRIANGLES",
           "MAX_STEP_WORK", "MAX_PINS", "MAX_GRASPS", "MAX_OBSTACLES", "MAX_WAYPOINTS",
           "BYTES_PER_TRIANGLE"]

#: Most triangles of the mesh a scene starts with (2^15: a uniform level-10 mesh on
#: 4 x 4 blocks, 16,641 particles; about 300 MB peak and 4 s of CPU to the first
#: frame on a 2-core machine, ``cloth-lod run`` of such a scene).
MAX_START_TRIANGLES = 2 ** 15
#: Most triangle-solves of the first step (2^21: the limit above with 64 solves; 31 s
#: at 15 us per triangle-solve if every solve the bound counts were taken).  The bound
#: multiplies every round that may run, and few do: the converged reference of
#: ``drop_on_sphere`` (uniform level 6, 3 Newton iterations, 6 friction rounds,
#: self-collision: 180 solves, 368,640 triangle-solves) takes 0.09 CPU s for its first
#: step; 2^18 refused it.
MAX_STEP_WORK = 2 ** 21
#: Most pins, grasps and obstacles of a scene.
MAX_PINS = 64
MAX_GRASPS = 32
MAX_OBSTACLES = 32
#: Most waypoint rows of all pins, grasps and obstacles together.
MAX_WAYPOINTS = 5000
#: Bytes of peak memory per triangle of the start mesh (measured slope, see above).
BYTES_PER_TRIANGLE = 4096


@dataclass(frozen=True)
class SceneCost:
    """Estimated cost of a scene's start (see the module text)."""
    triangles: int          # of the start mesh
    particles: int          # of the start mesh
    finest_triangles: int   # of the finest uniform mesh (the most LOD may reach)
    memory_bytes: int       # peak memory for the mesh, over the process's own
    solves_per_step: int    # most linear solves of one step
    step_work: int          # triangles x solves_per_step


def _disc_triangles(radius: float, level: int, side: float, area: float,
                    finest: int) -> int:
    """Triangles of a disc of ``radius`` (m) refined to ``level`` on blocks of
    ``side`` (m), its border widened by two legs; at most ``finest``."""
    tri_area = side * side / (2 * 2 ** level)            # m^2 of one level-l triangle
    leg = side / 2 ** (level / 2)
    disc = math.pi * (radius + 2 * leg) ** 2
    return min(finest, math.ceil(min(disc, area) / tri_area))


def estimate(scene) -> SceneCost:
    """The cost of starting ``scene`` (a validated ``SceneConfig``)."""
    cloth, lod = scene.cloth, scene.lod
    bu, bv = cloth.base_blocks
    finest = 2 * bu * bv * 2 ** cloth.level
    if lod.enabled:
        side = cloth.width / bu
        area = cloth.width * cloth.height
        tris = 2 * bu * bv * 2 ** lod.initial_level
        for pin in scene.pins:
            if pin.radius > 0:
                tris += _disc_triangles(pin.radius, cloth.level, side, area, finest)
        for _ in scene.grasps:
            tris += 4 * (cloth.level + 1)
            if lod.detail_level > 0:
                tris += _disc_triangles(lod.detail_radius, min(lod.detail_level, cloth.level),
                                        side, area, finest)
        tris = min(tris, finest)
    else:
        tris = finest
    sim = scene.simulation
    solves = (2 if sim.integrator == "sdirk2" else 1)
    if sim.integrator != "baraff_witkin":
        solves *= sim.newton_iterations
    if scene.obstacles:
        solves *= scene.contact.friction_rounds
    if scene.self_collision.enabled:    # `auto` counts as on: this bounds the step
        solves *= 1 + scene.self_collision.max_resolves
    return SceneCost(triangles=tris, particles=tris // 2 + math.isqrt(2 * tris) + 1,
                     finest_triangles=finest, memory_bytes=BYTES_PER_TRIANGLE * tris,
                     solves_per_step=solves, step_work=tris * solves)


def check_counts(data: Any) -> None:
    """Refuse a raw scene mapping with too many pins, grasps, obstacles or
    waypoint rows, before any of them is converted (cheap: lengths only)."""
    if not isinstance(data, dict):
        return
    rows = 0
    for key, limit in (("pins", MAX_PINS), ("grasps", MAX_GRASPS),
                       ("obstacles", MAX_OBSTACLES)):
        items = data.get(key)
        if not isinstance(items, (list, tuple)):
            continue
        if len(items) > limit:
            raise SceneError(f"field '{key}' has {len(items):,} entries; a scene may have at "
                             f"most {limit}")
        for item in items:
            path = item.get("waypoints") if isinstance(item, dict) else None
            if isinstance(path, (list, tuple)):
                rows += len(path)
    if rows > MAX_WAYPOINTS:
        raise SceneError(f"the scene's waypoints have {rows:,} rows in all; a scene may "
                         f"have at most {MAX_WAYPOINTS:,}")


def check(scene) -> SceneCost:
    """Refuse ``scene`` if its start exceeds the limits; return its cost."""
    cost = estimate(scene)
    cloth = scene.cloth
    mesh = (f"'cloth.base_blocks' {list(cloth.base_blocks)} and 'cloth.level' {cloth.level}"
            + (f" with 'lod.initial_level' {scene.lod.initial_level}" if scene.lod.enabled
               else " with LOD off"))
    about = (f"about {cost.triangles:,} triangles, {cost.particles:,} particles and "
             f"{cost.memory_bytes / 1e6:.0f} MB")
    if cost.triangles > MAX_START_TRIANGLES:
        raise SceneError(f"fields {mesh} start the cloth with {about}; the limit is "
                         f"{MAX_START_TRIANGLES:,} triangles at the start (with "
                         f"'lod.enabled' true the mesh starts coarse and refines)")
    if cost.step_work > MAX_STEP_WORK:
        raise SceneError(f"fields {mesh} and the step settings ask for {about} with up to "
                         f"{cost.solves_per_step} linear solves per step "
                         f"({cost.step_work:,} triangle-solves); the limit is "
                         f"{MAX_STEP_WORK:,}")
    return cost
