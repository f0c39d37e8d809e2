"""Level-of-detail policy: when to refine and when to simplify (paper §5.1, §5.4).

Policy only; the mechanism is :class:`cloth_lod_ros.sim.mesh.hierarchy.Hierarchy48`.

**Criterion** (paper §5.1, Fig. 6).  For each interior edge, θ is the angle
between the two triangle normals and L the mean distance of the two opposite
vertices from the edge.  The pair is replaced by two equal triangles of height
L on a circle through both apexes and the edge midpoint; the distance of the
flat pair from that arc is ``d = L (1 − cos(θ/2)) / (2 sin(θ/2))``, which is
``(L/2) tan(θ/4)``.  That form has no 0/0 at θ = 0.  ``d`` is in metres.

* **Refine** both triangles of every edge with ``d > refine_threshold`` (while
  below the maximum level; forced splits keep the mesh conforming).
* **Simplify** a split (merge its 4, or 2 on the border, children) only when:
  (a) every hinge touching its midpoint particle has ``d < coarsen_threshold``;
  (b) the hinges are *settled*.  The paper asks for ∂C/∂x ≈ 0, but that gradient
  has magnitude ~1/height even on a flat sheet (design §2).  What is small on
  a settled hinge is the rate ``dθ/dt = ∂θ/∂x · v`` and the bend force
  ``k_b c_e θ ∂θ/∂x``, so both are tested (``max_hinge_rate``, ``max_bend_force``);
  (c) each child triangle has existed for at least ``min_lifetime`` seconds
  (hysteresis against refine/simplify cycles; it never delays refinement);
  (d) no pin or contact holds the midpoint particle;
  (e) the merge adds to the cloth's total energy (elastic + kinetic + gravity,
  :mod:`cloth_lod_ros.sim.lod.merge_energy`) at most what would move its diamond
  at ``max_merge_speed``: ``ΔE ≤ ½ ρ A v²`` (ρ the areal density, A the
  diamond's rest area).  The hinge tests see bending only: a diamond stretched
  or sheared in its plane has flat hinges, but its coarse triangles replace
  the path through m by the chord and its stretch energy jumps (up to +0.96 mJ
  per merge measured on ``hang_two_corners`` before this test; design §4).
  Scaling the bound with the diamond's mass bounds the kick a merge gives,
  the same on every level: a fixed number of joules would be a large kick to
  a small fine diamond and a strict limit on a large coarse one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import check_kernels, policy_kernels, round_kernels
from ..physics.elements import Elements
from ..physics.hinges_kernels import hinge_angles       # compiled when numba is there
from ..mesh.hierarchy import Hierarchy48
from ..mesh.operations import Merge
from .merge_energy import merge_energy_change, merge_kinetic_change

__all__ = ["HingeMeasures", "hinge_measures", "curvature_estimate", "hinge_detail",
           "vertex_detail", "relative_thresholds", "LodPolicy", "LodDecision", "changed_hinges"]


def curvature_estimate(theta: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Paper's deviation ``d = L(1 − cos(θ/2)) / (2 sin(θ/2)) = (L/2) tan(|θ|/4)`` in m.

    Args:
        theta: hinge angles, rad.
        height: mean distance L of the two opposite vertices from the edge, m.
    """
    return 0.5 * height * np.tan(0.25 * np.abs(theta))


def hinge_detail(uv: np.ndarray, hinge_vertices: np.ndarray, field: np.ndarray) -> np.ndarray:
    """How far the two triangles of each hinge miss a smooth ``field``: ``|[∇f] n̂| L / 8``.

    On each triangle the mesh represents ``field`` (positions, m, or
    velocities, m/s) by the linear interpolant of its corners, whose gradient
    is the deformation gradient ``F = ∂f/∂(u, v)`` ``(3, 2)``.  Along the
    shared edge both gradients agree; across it they jump by ``[∇f] n̂``
    (``n̂`` the edge's unit normal in the rest plane).  A smooth field with
    that jump over the two triangles' mean height ``L`` misses their
    piecewise-linear interpolant by about ``|[∇f] n̂| L / 8`` (the edge-midpoint
    error of linear interpolation, ``h² f'' / 8``, with ``f'' ≈ [∇f] n̂ / L``;
    a-posteriori estimators of this kind: Verfürth, *A Posteriori Error
    Estimation Techniques for Finite Element Methods*, 2013, ch. 1).  For a
    pure fold by θ of an unstretched cloth ``|[∇x] n̂| = 2 sin(θ/2)``, so the
    estimate is ``L sin(θ/2) / 4``, the paper's ``(L/2) tan(θ/4)`` to second
    order; unlike it, it also sees stretch that varies in the plane and, with
    velocities, a motion the coarse triangles cannot carry.  Zero for every
    affine field (exactly representable).

    Args:
        uv: ``(n, 2)`` rest (material) coordinates, m.
        hinge_vertices: ``(h, 4)`` compact ids: the edge's ends, then the two
            opposite corners.
        field: ``(n, 3)`` values at the particles (m or m/s).

    Returns:
        ``(h,)`` in the field's unit (m or m/s).
    """
    hv = np.asarray(hinge_vertices, dtype=np.int64).reshape(-1, 4)
    if not len(hv):
        return np.zeros(0)
    ua, ub, u1, u2 = uv[hv[:, 0]], uv[hv[:, 1]], uv[hv[:, 2]], uv[hv[:, 3]]
    fa, fb, f1, f2 = field[hv[:, 0]], field[hv[:, 1]], field[hv[:, 2]], field[hv[:, 3]]
    t = ub - ua
    length2 = (t * t).sum(axis=1)
    normal = np.column_stack([-t[:, 1], t[:, 0]]) / np.sqrt(length2)[:, None]
    jump = np.zeros_like(fa)
    heights = np.zeros(len(hv))
    for uk, fk, sign in ((u1, f1, -1.0), (u2, f2, 1.0)):
        r = uk - ua
        along = (r * t).sum(axis=1) / length2          # position along the edge, 0..1
        across = (r * normal).sum(axis=1)              # signed height, m
        # F n̂ of this triangle: the change of f across the edge per metre.
        slope = (fk - fa - along[:, None] * (fb - fa)) / across[:, None]
        jump += sign * slope
        heights += 0.5 * np.abs(across)
    return np.sqrt((jump * jump).sum(axis=1)) * heights / 8.0


def vertex_detail(field: np.ndarray, vertices: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Hierarchical detail of split particles: ``|f_m − (f_a + f_b) / 2|``.

    A split puts ``m`` at the rest midpoint of its edge ``(a, b)``, so this is
    what the merge that removes ``m`` would lose of ``field`` (``(n, 3)``, m
    or m/s): zero for every field affine in (u, v), ``κ ℓ² / 8`` for a
    surface of normal curvature κ along an edge of rest length ℓ.

    Args:
        field: ``(n, 3)`` compact values.
        vertices: ``(k,)`` compact ids of the split particles.
        ends: ``(k, 2)`` compact ids of their edges' ends.

    Returns:
        ``(k,)`` in the field's unit.
    """
    ends = np.asarray(ends, dtype=np.int64).reshape(-1, 2)
    delta = field[np.asarray(vertices, dtype=np.int64)] - 0.5 * (field[ends[:, 0]]
                                                                  + field[ends[:, 1]])
    return np.sqrt((delta * delta).sum(axis=1))


def relative_thresholds(config, cloth) -> tuple[float, float]:
    """``(refine, coarsen)`` thresholds, m: the config's, or with ``tolerance``
    set, ``tolerance · h² / side`` and that times the config's coarsen/refine
    ratio.  ``h`` is the leg of a triangle at the finest level
    (``block · 2^(−level/2)``), ``side`` the cloth's larger side: a surface of
    curvature 1/side leaves a detail ``h²/(8 side)`` at that level, so the
    threshold follows the accuracy the maximum level can give, and one more
    level halves it (a run with a higher maximum level refines at least where
    the lower one did).  ``cloth``: the scene's ClothConfig."""
    refine, coarsen = float(config.refine_threshold), float(config.coarsen_threshold)
    tolerance = getattr(config, "tolerance", None)
    if tolerance is None or cloth is None:
        return refine, coarsen
    block = min(cloth.width / cloth.base_blocks[0], cloth.height / cloth.base_blocks[1])
    side = max(cloth.width, cloth.height)
    relative = float(tolerance) * block * block * 2.0 ** (-cloth.level) / side
    return relative, relative * coarsen / refine


@dataclass
class HingeMeasures:
    """Per-hinge quantities of the criterion, ``(h,)`` each.

    Attributes:
        deviation: d in m; rate: dθ/dt in rad/s; bend_force: largest bend force
        on the hinge's four particles, N; angle: θ in rad; height: L in m.
    """

    deviation: np.ndarray
    rate: np.ndarray
    bend_force: np.ndarray
    angle: np.ndarray
    height: np.ndarray


def hinge_measures(elements: Elements, bend_stiffness: float, x: np.ndarray,
                   v: np.ndarray, evaluation=None) -> HingeMeasures:
    """Evaluate the criterion on every hinge (vectorised).

    The heights come from the angle gradient: ``|∂θ/∂o_k| = 1/h_k``.  With an
    ``evaluation`` of the same state (:func:`cloth_lod_ros.sim.physics.forces.evaluate`),
    its hinge angles and gradients are reused instead of recomputed.
    """
    return _criterion(elements, bend_stiffness, x, v, evaluation)[0]


def _criterion(elements: Elements, bend_stiffness: float, x: np.ndarray, v: np.ndarray,
               evaluation=None, lookahead: float = 0.0) -> tuple[HingeMeasures, np.ndarray]:
    """:func:`hinge_measures` and the deviation refined on, ``(h,)`` m: the larger
    of d now and at ``θ + lookahead · dθ/dt`` (lookahead in s; 0: d itself).

    One compiled pass (:mod:`cloth_lod_ros.sim.lod.policy_kernels`, bitwise the same
    numbers) when the kernels are on; this numpy code is the reference.
    """
    hv = elements.hinge_vertices
    if len(hv) == 0:
        empty = np.zeros(0)
        return HingeMeasures(empty, empty, empty, empty, empty), empty
    compiled = policy_kernels.criterion(elements, bend_stiffness, x, v, evaluation, lookahead)
    if compiled is not None:
        deviation, refine_deviation, rate, force, height, theta = compiled
        return HingeMeasures(deviation, rate, force, theta, height), refine_deviation
    if evaluation is not None:
        theta, grad = evaluation.hinge_angle, evaluation.hinge_gradient
    else:
        theta, grad = hinge_angles(x, hv, with_gradient=True)
    # |∂θ/∂x_k| written out: the same sums in the same order as
    # np.linalg.norm(grad, axis=2), which reduces over the length-3 axis ~10x slower.
    squares = grad * grad
    grad_norm = np.sqrt(squares[..., 0] + squares[..., 1] + squares[..., 2])   # (h, 4)
    height = 0.5 * (1.0 / grad_norm[:, 2] + 1.0 / grad_norm[:, 3])
    rate = np.einsum("hkd,hkd->h", grad, v[hv])
    # Largest of the four norms by column maxima (exact; a reduction along
    # the length-4 axis costs several times more).
    largest = np.maximum(np.maximum(grad_norm[:, 0], grad_norm[:, 1]),
                         np.maximum(grad_norm[:, 2], grad_norm[:, 3]))
    force = bend_stiffness * elements.hinge_weight * np.abs(theta) * largest
    deviation = curvature_estimate(theta, height)
    measures = HingeMeasures(deviation, rate, force, theta, height)
    if lookahead > 0.0:
        ahead = np.clip(theta + lookahead * rate, -np.pi, np.pi)
        deviation = np.maximum(deviation, curvature_estimate(ahead, height))
    return measures, deviation


_NO_TRIANGLES = np.zeros(0, dtype=np.int64)   # writeable: numba types read-only arrays apart


@dataclass
class LodDecision:
    """Pool triangle ids to refine (most curved first) and split edges to merge.

    ``merge_energy``, ``merge_kinetic`` and ``merge_bound`` (``(len(merge),)``,
    J) are the energy each merge was tested to add, its kinetic part and the
    most it may add.
    """

    refine: list
    merge: list
    merge_energy: np.ndarray | None = None
    merge_kinetic: np.ndarray | None = None
    merge_bound: np.ndarray | None = None


class LodPolicy:
    """Decides refinements and simplifications from the current state.

    Args:
        config: :class:`cloth_lod_ros.sim.scene.config.LodConfig`.
        material: :class:`cloth_lod_ros.sim.scene.config.MaterialConfig` (k_b for the
            bend-force test, all stiffnesses for the merge energy test).
        gravity: ``(3,)`` m/s² (for the merge energy test).
        cloth: :class:`cloth_lod_ros.sim.scene.config.ClothConfig`, for the
            thresholds of ``config.tolerance`` (:func:`relative_thresholds`;
            None: the thresholds as given).
    """

    def __init__(self, config, material, gravity=(0.0, 0.0, 0.0), cloth=None):
        refine, coarsen = relative_thresholds(config, cloth)
        if (refine, coarsen) != (config.refine_threshold, config.coarsen_threshold):
            config = replace(config, refine_threshold=refine, coarsen_threshold=coarsen)
        self.config = config
        self.material = material
        self.gravity = np.asarray(gravity, dtype=float)
        self.detail = getattr(config, "criterion", "curvature") == "detail"
        # The detail criterion's velocity term is what "settled" means to it:
        # the hinge rate and bend force tests of the curvature criterion
        # (absolute limits, which a cloth resting on a curved support never
        # meets) are off.
        self._merge_config = (replace(config, max_hinge_rate=np.inf, max_bend_force=np.inf)
                              if self.detail else config)

    def decide(self, hierarchy: Hierarchy48, elements: Elements, vertex_ids: np.ndarray,
               triangle_ids: np.ndarray, x: np.ndarray, v: np.ndarray, masses: np.ndarray,
               time: float, held: np.ndarray, detail_points: np.ndarray | None = None,
               in_contact: np.ndarray | None = None, supported=None,
               evaluation=None, simplify: bool = True,
               lookahead: float = 0.0, layered: np.ndarray | None = None,
               layered_level: int = 0, recheck=None) -> LodDecision:
        """Choose operations for the active mesh described by the compact arrays.

        Args:
            hierarchy: the mesh being adapted (read only here).
            elements: rest data of the compact mesh.
            vertex_ids, triangle_ids: pool ids of the compact vertices/triangles.
            x, v: ``(n, 3)`` compact positions (m) and velocities (m/s).
            masses: ``(n,)`` compact masses, kg.
            time: simulation time, s.
            held: pool ids of particles held by pins or grasps (never merged).
            detail_points: ``(k, 2)`` (u, v) points (closed grasps) around which
                the mesh is kept at ``detail_level`` within ``detail_radius``.
            in_contact: ``(n,)`` how many obstacles each compact particle
                touches (0, 1 or 2, or bool); triangles on the border of the
                contact region, or touching a particle between two obstacles,
                get ``detail_level``, and the latter are not merged.
            supported: callable(pool vertex ids) -> bool mask of split particles
                an obstacle is holding up (merging them would sink the coarse
                edge into it); those are not merged.
            evaluation: the force evaluation of this state, to reuse its hinge
                angles and gradients.
            simplify: also look for merges (False: refinements only; the
                merge tests, the dearest part of the criterion, are skipped).
            lookahead: s until the criterion is next evaluated.  A hinge is
                refined now if its deviation exceeds the threshold now or
                would at ``θ + lookahead · dθ/dt`` (so a mesh checked every k
                steps is refined as early as one checked at every step; 0:
                the paper's rule).
            layered: ``(n,)`` compact particles close to another layer of the
                cloth (self-collision): no merge touches them (a merge moves
                the surface, and could push it into the other layer), and
                triangles with such a corner are refined to ``layered_level``.
            recheck: for a check right after a decision was carried out
                (``LodPolicy.apply`` at this ``time``, on this state), that
                decision's merge edges (``(k, 2)`` pool ids, or its list).  With
                ``simplify`` off the criterion is then evaluated on the hinges
                those operations changed only (:func:`changed_hinges`): any
                other hinge was evaluated by that decision with the same
                result, and one over the threshold had both triangles refined
                there unless they are at the maximum level, so it adds no
                refinement now.  The same decision, for less.
        """
        cfg = self.config
        detail = self._detail_triangles(elements, hierarchy, triangle_ids, detail_points,
                                        in_contact)
        layers_near = layered is not None and layered.any()
        if layers_near and layered_level > 0:
            near = layered[elements.triangles].any(axis=1)
            low = hierarchy.level[triangle_ids] < layered_level
            detail = np.union1d(detail, triangle_ids[near & low])
        if (not self.detail and evaluation is None and recheck is None and supported is None
                and not layers_near
                and not (in_contact is not None and (in_contact > 1).any())
                and not (cfg.detail_level > 0 and detail_points is not None
                         and len(detail_points))):
            # No filter between the steps below: all of them in one compiled call.
            plain = check_kernels.plain_decision(
                hierarchy, elements, vertex_ids, triangle_ids, x, v, masses, time, held, cfg,
                self.material, self.gravity, lookahead, detail, simplify)
            if plain is not None:
                return LodDecision(*plain)
        hinges, hinge_tris = elements, elements.hinge_triangles
        if recheck is not None and not simplify and evaluation is None:
            changed = changed_hinges(elements, hierarchy, vertex_ids, triangle_ids, time,
                                     recheck)
            hinges = _HingeSubset(elements.hinge_vertices[changed],
                                  elements.hinge_weight[changed])
            hinge_tris = hinge_tris[changed]
        measures, deviation = _criterion(hinges, self.material.bend_stiffness, x, v,
                                         evaluation, lookahead)
        if self.detail:
            uv = hierarchy.uv[vertex_ids]
            moved = hinge_detail(uv, hinges.hinge_vertices, x)
            moving = hinge_detail(uv, hinges.hinge_vertices, v)
            horizon = cfg.velocity_horizon
            measures.deviation = moved + horizon * moving
            # Refine what will be over the threshold by the next check.
            deviation = moved + (horizon + lookahead) * moving
        # Refine: both triangles of each over-curved hinge, most curved first.
        refine = policy_kernels.refine_order(deviation, cfg.refine_threshold, hinge_tris,
                                             triangle_ids, hierarchy.level, hierarchy.max_level,
                                             detail)
        if refine is None:                      # the reference (one compiled pass above)
            refine = []
            over = np.flatnonzero(deviation > cfg.refine_threshold)
            order = over[np.argsort(-deviation[over], kind="stable")]
            if len(order) or len(detail):
                candidates = np.concatenate([triangle_ids[hinge_tris[order].ravel()], detail])
                levels = hierarchy.level[candidates]
                candidates = candidates[levels < hierarchy.max_level]
                _, first = np.unique(candidates, return_index=True)
                refine = candidates[np.sort(first)].tolist()

        uniform = False
        if self.detail and cfg.uniform_share < 1.0 and len(triangle_ids):
            refine, uniform = self._uniform_when_most_is_fine(hierarchy, triangle_ids, refine)

        # Simplify: split particles all of whose hinges are flat and settled.
        merge, energy, kinetic, bound = [], np.zeros(0), np.zeros(0), np.zeros(0)
        vertices, kids, ok = np.zeros(0, int), None, None
        if simplify:        # Hierarchy48.split_vertices and tests (a)-(d), or their twins
            found = policy_kernels.merge_candidates(hierarchy, elements.hinge_vertices, measures,
                                                    self._merge_config, vertex_ids,
                                                    time - cfg.min_lifetime, held)
            if found is None:
                vertices, kids = hierarchy.split_vertices()
            else:
                vertices, kids, ok = found
        if len(vertices):
            if ok is None:
                ok = policy_kernels.mergeable(elements.hinge_vertices, measures,
                                              self._merge_config, vertex_ids,
                                              vertices, kids, hierarchy.birth,
                                              time - cfg.min_lifetime, held, hierarchy.vertex_end)
            if ok is None:                       # the reference (one compiled pass above)
                limits = self._merge_config
                unsettled = ((measures.deviation >= cfg.coarsen_threshold)
                             | (np.abs(measures.rate) >= limits.max_hinge_rate)
                             | (measures.bend_force >= limits.max_bend_force))
                blocked = np.zeros(len(x), dtype=bool)
                blocked[elements.hinge_vertices[unsettled].ravel()] = True
                # Youngest child (padding -1 never young), by column maxima (exact).
                births = np.where(kids >= 0, hierarchy.birth[np.maximum(kids, 0)], -np.inf)
                young = (np.maximum(np.maximum(births[:, 0], births[:, 1]),
                                    np.maximum(births[:, 2], births[:, 3]))
                         > time - cfg.min_lifetime)
                is_held = np.zeros(hierarchy.vertex_end, dtype=bool)   # np.isin by a pool mask
                is_held[np.asarray(held, dtype=np.int64)] = True
                ok = ~(blocked[np.searchsorted(vertex_ids, vertices)] | young
                       | is_held[vertices])
            if self.detail and ok.any():
                # What the merge itself loses: the split particle's
                # hierarchical detail in position and velocity.
                mid = np.searchsorted(vertex_ids, vertices[ok])
                ends = np.searchsorted(vertex_ids, hierarchy.vertex_edge[vertices[ok]])
                lost = (vertex_detail(x, mid, ends)
                        + cfg.velocity_horizon * vertex_detail(v, mid, ends))
                ok[ok] = lost < cfg.coarsen_threshold
            if cfg.detail_level > 0 and detail_points is not None and len(detail_points):
                # Keep grasp neighbourhoods at detail_level: a merge there would
                # leave parents one level above their children's.
                near = _near(hierarchy.uv[vertices], detail_points, cfg.detail_radius)
                child_level = hierarchy.level[np.maximum(kids[:, 0], 0)]
                ok &= ~(near & (child_level - 1 < cfg.detail_level))
            if supported is not None and ok.any():
                ok[ok] &= ~supported(vertices[ok])
            for keep_out in (layered, None if in_contact is None else in_contact > 1):
                # Nothing merges next to another layer or a particle between
                # two obstacles (what the detail above refined stays).
                if keep_out is not None and keep_out.any():
                    ends = np.searchsorted(vertex_ids, hierarchy.vertex_edge[vertices])
                    ok &= ~(keep_out[np.searchsorted(vertex_ids, vertices)]
                            | keep_out[ends].any(axis=1))
            # (e) the merge adds at most ½ ρ A v² (elastic + kinetic + gravity).
            keep = np.flatnonzero(ok)
            added = merge_energy_change(hierarchy, elements, vertex_ids, triangle_ids,
                                        vertices[keep], x, v, masses, self.material,
                                        self.gravity)
            bound = 0.5 * self.material.density * added.area * cfg.max_merge_speed**2
            low = added.total <= bound
            keep = keep[low]
            if uniform:
                # Merge out of the uniform mesh only when enough goes at once.
                fine = hierarchy.level[np.maximum(kids[keep, 0], 0)] >= hierarchy.max_level
                counts = (kids[keep] >= 0).sum(axis=1)
                merged = (counts * 2.0 ** -hierarchy.level[np.maximum(kids[keep, 0], 0)])[fine]
                total = (2.0 ** -hierarchy.level[triangle_ids]).sum()
                if 1.0 - merged.sum() / total >= 0.8 * cfg.uniform_share:
                    keep = keep[:0]
                    low = low[:0]
            merge = [(a, b) for a, b in hierarchy.vertex_edge[vertices[keep]].tolist()]
            energy, kinetic, bound = added.total[low], added.kinetic[low], bound[low]
        return LodDecision(refine, merge, energy, kinetic, bound)

    def _uniform_when_most_is_fine(self, hierarchy: Hierarchy48, triangle_ids: np.ndarray,
                                   refine) -> tuple[list, bool]:
        """When to stop adapting: if the share of the cloth's area at the maximum
        level, counting what ``refine`` (pool ids) takes there, reaches
        ``uniform_share``, every active triangle below it is refined instead (a
        uniform mesh costs no more than an adaptive one that is almost all fine,
        and saves the criterion's churn).  Returns the refinements and whether
        the mesh is (to be) uniform."""
        top = hierarchy.max_level
        levels = hierarchy.level[triangle_ids]
        area = 2.0 ** -levels.astype(float)       # in base-triangle areas
        listed = np.zeros(hierarchy.level.shape[0], dtype=bool)
        listed[np.asarray(refine, dtype=np.int64)] = True
        going = listed[triangle_ids] & (levels == top - 1)
        share = (area[levels >= top].sum() + area[going].sum()) / area.sum()
        if share < self.config.uniform_share:
            return refine, False
        below = triangle_ids[levels < top]
        return below[np.argsort(levels[levels < top], kind="stable")].tolist(), True

    def recheck_on_pools(self, hierarchy: Hierarchy48, time: float, merged,
                         detail_points: np.ndarray | None, lookahead: float):
        """The refinements :meth:`decide` makes with ``simplify`` off and
        ``recheck=merged`` on the mesh the hierarchy has now, found on its pools
        (:mod:`~cloth_lod_ros.sim.lod.round_kernels`): the same list, without
        adopting the mesh first.  For a check's later rounds when no contact
        counts (``in_contact`` None) and no layer is near (``layered`` None).
        None when the kernels are off or cannot take the hierarchy: then adopt
        and :meth:`decide`.  The refinements as a ``(r,)`` int64 array."""
        if self.detail:                         # computed on the adopted mesh only
            return None
        detail = (self._detail_triangles(None, hierarchy, hierarchy.active_triangles(),
                                         detail_points, None)
                  if self.config.detail_level > 0 else _NO_TRIANGLES)
        return round_kernels.changed_hinge_refinements(
            hierarchy, time, merged, self.material.bend_stiffness, lookahead,
            self.config.refine_threshold, detail)

    def _detail_triangles(self, elements, hierarchy, triangle_ids, detail_points,
                          in_contact) -> np.ndarray:
        """Pool ids of triangles below ``detail_level`` that need it."""
        cfg = self.config
        if cfg.detail_level <= 0:
            return np.zeros(0, dtype=np.int64)
        levels = hierarchy.level[triangle_ids]
        want = np.zeros(len(triangle_ids), dtype=bool)
        if detail_points is not None and len(detail_points):
            centroid = hierarchy.uv[hierarchy.tri[triangle_ids]].mean(axis=1)
            want |= _near(centroid, detail_points, cfg.detail_radius)
        if in_contact is not None and in_contact.any():
            touching = in_contact[elements.triangles]
            low, high = touching.min(axis=1), touching.max(axis=1)
            # The border of the contact patch, and where the cloth meets a
            # second obstacle (a box's face pushing it on the table): the
            # contact's edge, where it folds or wrinkles.
            want |= (low != high) | (high > 1)
        return triangle_ids[want & (levels < cfg.detail_level)]

    @staticmethod
    def apply(hierarchy: Hierarchy48, decision: LodDecision, time: float,
              log: list | None = None) -> tuple[int, int]:
        """Carry out a decision; returns ``(splits, merges)`` performed.

        Refinements go first; merges only touch all-leaf diamonds, which keeps
        the mesh conforming.  The energy a merge adds was tested on the state
        before the decision (:func:`~cloth_lod_ros.sim.lod.merge_energy.merge_energy_change`).
        An earlier operation of the same decision changes it through the mass
        or velocity of one of its edge ends (its kinetic part is then computed
        again, and the merge skipped if the total now exceeds its bound), by
        replacing a triangle across one of its diamond's outer edges (the
        merge is skipped), or through the bending stencils a few rings around
        it (not tested again: its bend part is the one decided).  So every
        merge adds at most its bound up to that last part.  A skipped merge,
        or one a split made invalid, is decided again at the next check.  With
        ``log``, every operation performed is appended to it in order (undo:
        apply their inverses in reverse).

        With the compiled kernels, :meth:`Hierarchy48.carry_out` does all of
        this in one call (the code below is its reference; same results).
        """
        if not len(decision.refine) and not len(decision.merge):
            return 0, 0
        done = hierarchy.carry_out(decision.refine, decision.merge, time,
                                   decision.merge_energy, decision.merge_kinetic,
                                   decision.merge_bound, log)
        if done is not None:
            return done
        moved: set[int] = set()          # particles whose mass or velocity changed
        changed: set = set()             # edges whose triangles were replaced
        splits = []
        for t in decision.refine:
            for op in hierarchy.refine(int(t), time):
                splits.append(op)
                if log is not None:
                    log.append(op)
                moved.update(op.edge)
                for parent in hierarchy.vertex_parents[hierarchy.midpoint[op.edge]].tolist():
                    if parent >= 0:
                        changed.update(_edges(hierarchy.tri[parent].tolist()))
        merges = 0
        for i, edge in enumerate(decision.merge):
            m = hierarchy.midpoint.get(edge)
            if m is None:
                continue
            if moved.intersection(edge) and decision.merge_energy is not None:
                # An end's mass or velocity changed: the kinetic part, again.
                particles = [m, *edge]
                kinetic = merge_kinetic_change(
                    hierarchy.mass_units[particles][None] * hierarchy.unit_mass,
                    hierarchy.v[particles][None])[0]
                if (decision.merge_energy[i] - decision.merge_kinetic[i] + kinetic
                        > decision.merge_bound[i]):
                    continue
            parents = [t for t in hierarchy.vertex_parents[m].tolist() if t >= 0]
            outer = [e for t in parents for e in _edges(hierarchy.tri[t].tolist())[::2]]
            active = hierarchy.tri_active
            if (all(active[k] for t in parents for k in hierarchy.children[t].tolist())
                    and changed.isdisjoint(outer)):
                hierarchy.apply(Merge(edge), time)
                merges += 1
                if log is not None:
                    log.append(Merge(edge))
                moved.update(edge)
                changed.update(outer)
        return len(splits), merges


@dataclass
class _HingeSubset:
    """Some hinges of an :class:`Elements`: what :func:`_criterion` reads."""

    hinge_vertices: np.ndarray
    hinge_weight: np.ndarray


def changed_hinges(elements: Elements, hierarchy: Hierarchy48, vertex_ids: np.ndarray,
                   triangle_ids: np.ndarray, time: float, merged) -> np.ndarray:
    """Compact hinges (increasing ids) that carrying out a decision at ``time`` s
    may have changed: those with a triangle (re)activated then (born at
    ``time``: split children and merged parents) or a particle whose velocity
    one of its merges changed (the ends of ``merged``, ``(k, 2)`` pool ids).
    Splits and merges move no other particle and change no other velocity,
    so every other hinge has the corners, positions and velocities it had.
    A superset is harmless (triangles born at ``time`` in an earlier round)."""
    born = hierarchy.birth[triangle_ids] == time
    ht = elements.hinge_triangles
    changed = born[ht[:, 0]] | born[ht[:, 1]]
    ends = np.asarray(merged, dtype=np.int64).reshape(-1)
    if len(ends) and len(vertex_ids):
        at = np.minimum(np.searchsorted(vertex_ids, ends), len(vertex_ids) - 1)
        moved = np.zeros(len(vertex_ids), dtype=bool)
        moved[at[vertex_ids[at] == ends]] = True
        hv = elements.hinge_vertices
        changed |= moved[hv[:, 0]] | moved[hv[:, 1]] | moved[hv[:, 2]] | moved[hv[:, 3]]
    return np.flatnonzero(changed)


def _edges(corners) -> list:
    """Sorted vertex pairs of a triangle ``(apex, left, right)``: leg, hypotenuse, leg."""
    a, b, c = corners            # Python ints (``tolist``)
    return [(min(a, b), max(a, b)), (min(b, c), max(b, c)), (min(c, a), max(c, a))]



def _near(points: np.ndarray, centres: np.ndarray, radius: float) -> np.ndarray:
    """Whether each ``(m, 2)`` point is within ``radius`` of any of ``centres`` ``(k, 2)``."""
    d2 = ((points[:, None, :] - centres[None, :, :]) ** 2).sum(axis=-1)
    return (d2 <= radius * radius).any(axis=1)
