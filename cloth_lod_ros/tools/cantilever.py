"""Peirce's cantilever (ASTM D1388) as a measurement of the bending rigidity.

A strip clamped horizontally and overhanging by ``l`` droops under its own
weight.  For an inextensible heavy elastica with rigidity ``B`` (N·m, per unit
width) and weight ``w`` (N/m², per unit area) the shape depends on ``l/c``
only, with the bending length ``c = (B/w)^(1/3)``; the chord from the clamp
to the tip makes 41.5° with the horizontal at ``l = 2c`` (Peirce, "The
'handle' of cloth as a measurable quantity", J. Textile Inst. 21, 1930;
ASTM D1388).  Measuring the simulated strip's chord angle and inverting that
relation gives the rigidity the simulation really has.

The elastica: with θ(s) the tangent's angle below the horizontal at arc
length s from the clamp, the overhang beyond s weighs ``w (l − s)`` per unit
width and its moment about s, ``∫_s^l w cos θ(σ)·(σ − s) dσ`` differentiated
twice, gives ``B θ'' = −w (l − s) cos θ`` with ``θ(0) = 0`` (clamped) and
``θ'(l) = 0`` (no moment at the free tip).  In σ = s/l:
``θ'' = −(l/c)³ (1 − σ) cos θ``.  Solved by ``scipy.integrate.solve_bvp``
with continuation in l/c (the large-deflection branch starts from the
previous solution).

The simulated strip (:func:`simulate`): 5 cm wide, the first 20 cm held flat
(every particle there: a straight clamp line, so l is exact), stretch
2·10⁴ N/m, no air, an isotropic drag and large backward-Euler steps to bring
it to rest.  Directions: a strip along u or v at an even level has its edges
on the mesh lines; at an odd level the interior of a 4-8 mesh is the even
level's pattern turned by 45° (its legs are the diagonals of the even
lattice), so a strip along u at an odd level is a strip cut along the
diagonal of that mesh (its border triangles differ: hypotenuses lie on the
border).

Run ``python -m cloth_lod_ros.tools.cantilever`` for the table.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.integrate import quad, solve_bvp
from scipy.optimize import brentq

__all__ = ["elastica_chord_angle", "implied_length_ratio", "simulate", "implied_rigidity"]

CLAMP = 0.2          # m of strip held flat
WIDTH = 0.05         # m
BLOCK = 0.05         # m, level-0 block side


def _elastica(lc: float, guess=None):
    a = lc ** 3
    s = np.linspace(0.0, 1.0, 201)

    def rhs(sigma, y):
        return np.vstack([y[1], -a * (1.0 - sigma) * np.cos(y[0])])

    def bc(ya, yb):
        return np.array([ya[0], yb[1]])

    y0 = np.zeros((2, len(s))) if guess is None else guess(s)
    sol = solve_bvp(rhs, bc, s, y0, tol=1e-10, max_nodes=200000)
    if not sol.success:
        raise RuntimeError(f"elastica at l/c = {lc}: {sol.message}")
    return sol


def _solutions(lc: float):
    """The elastica at l/c, reached by continuation from 0.5 in small steps."""
    sol = None
    for value in np.append(np.arange(0.5, lc, 0.25), lc):
        sol = _elastica(value, None if sol is None else sol.sol)
    return sol


def elastica_chord_angle(lc: float) -> float:
    """Angle (rad) below the horizontal of the chord clamp → tip of the heavy
    elastica with overhang ``l`` = ``lc`` bending lengths."""
    sol = _solutions(lc)
    x = quad(lambda t: np.cos(sol.sol(t)[0]), 0.0, 1.0, epsabs=1e-13, limit=200)[0]
    y = quad(lambda t: np.sin(sol.sol(t)[0]), 0.0, 1.0, epsabs=1e-13, limit=200)[0]
    return float(np.arctan2(y, x))


_TABLE: tuple | None = None


def implied_length_ratio(angle: float) -> float:
    """The l/c whose elastica has chord angle ``angle`` (rad), from a table of
    solutions over l/c ∈ [0.1, 4] (monotone there) refined by root finding."""
    global _TABLE
    if _TABLE is None:
        lcs = np.linspace(0.1, 4.0, 79)
        sol = None
        angles = []
        for lc in lcs:
            sol = _elastica(lc, None if sol is None else sol.sol)
            x = quad(lambda t: np.cos(sol.sol(t)[0]), 0.0, 1.0, epsabs=1e-13, limit=200)[0]
            y = quad(lambda t: np.sin(sol.sol(t)[0]), 0.0, 1.0, epsabs=1e-13, limit=200)[0]
            angles.append(np.arctan2(y, x))
        _TABLE = (lcs, np.array(angles))
    lcs, angles = _TABLE
    k = int(np.searchsorted(angles, angle))
    if k == 0 or k == len(lcs):
        raise ValueError(f"chord angle {np.degrees(angle):.3f}° outside the table")
    return brentq(lambda lc: elastica_chord_angle(lc) - angle, lcs[k - 1], lcs[k], xtol=1e-10)


def implied_rigidity(angle: float, overhang: float, weight: float) -> float:
    """Rigidity B (N·m) of an elastica of overhang ``overhang`` (m) and weight
    ``weight`` (N/m²) whose chord makes ``angle`` (rad): ``w (l / (l/c))³``."""
    return weight * (overhang / implied_length_ratio(angle)) ** 3


def _scene(level: int, overhang: float, along: str, lod: bool, bend: float,
           density: float, drag: float, step: float, initial_level: int):
    from ..sim.scene.config import scene_from_dict
    length = CLAMP + overhang
    blocks = int(round(length / BLOCK))
    if along == "u":
        cloth = {"width": length, "height": WIDTH, "base_blocks": [blocks, 1],
                 "u_axis": [1.0, 0.0, 0.0], "v_axis": [0.0, 1.0, 0.0]}
        root = [0.0, 0.5 * WIDTH]
    else:
        cloth = {"width": WIDTH, "height": length, "base_blocks": [1, blocks],
                 "u_axis": [0.0, 1.0, 0.0], "v_axis": [1.0, 0.0, 0.0]}
        root = [0.5 * WIDTH, 0.0]
    cloth.update(level=level, origin=[0.0, 0.0, 0.0])
    return scene_from_dict({
        "name": "cantilever",
        "cloth": cloth,
        "material": {"density": density, "stretch_stiffness": 2e4, "shear_stiffness": 2e3,
                     "bend_stiffness": bend, "air_drag": drag, "stretch_damping": 0.0,
                     "shear_damping": 0.0, "bend_damping": 0.0},
        "air": {"density": 0.0},
        "pins": [{"name": "clamp", "uv": root}],
        "simulation": {"time_step": step, "duration": 1.0, "integrator": "backward_euler",
                       "error_tolerance": 0.0, "newton_iterations": 1},
        "solver": {"method": "direct", "tolerance": 1e-10},
        "lod": {"enabled": lod, "initial_level": initial_level if lod else 0},
    })


def simulate(level: int, lc: float, along: str = "u", lod: bool = False,
             c: float = 0.1, density: float = 0.2, drag: float = 3.0, step: float = 0.3,
             max_steps: int = 2000, tolerance: float = 1e-7, initial_level: int = 2,
             clamp_weight: float = 1.0):
    """Chord angle (rad) of the simulated strip at rest, and the sim.

    Args:
        level: mesh level (the maximum level with ``lod``).
        lc: overhang in bending lengths; ``c`` (m) sets ``B = w c³``.
        along: ``"u"`` or ``"v"``: the material direction of the strip.
        lod: adaptive mesh (refined over the clamp to ``level`` at the start).
        density: kg/m²; drag: isotropic drag 1/s; step: s per backward-Euler step.
        tolerance: at rest when the tip moved less than this (m) over 10 steps.
        clamp_weight: factor on the weight of the hinges on the clamp line (LOD
            off): 2 gives them only the free half of their dual area.
    """
    from ..sim import ClothSim
    weight = density * 9.81
    overhang = lc * c
    scene = _scene(level, overhang, along, lod, weight * c ** 3, density, drag, step,
                   initial_level)
    sim = ClothSim(scene)
    axis = 0 if along == "u" else 1
    if lod:
        # The clamp region at the full level (as a pin patch is, design §2), so
        # the clamp holds the uniform mesh's particles; nothing split later is free there.
        h = sim.hierarchy
        for _ in range(2 * level + 2):
            before = len(h.active_triangles())
            for t in h.active_triangles():
                if h.tri_active[t] and h.uv[h.tri[t]].mean(axis=0)[axis] < CLAMP + 1e-9 \
                        and h.level[t] < level:
                    h.refine(int(t))
            if len(h.active_triangles()) == before:
                break
        sim._adopt_hierarchy()
    pin = sim.pins[0]
    held = np.flatnonzero(sim.rest_uv[:, axis] <= CLAMP + 1e-9)
    pin.nodes = sim.vertex_ids[held].astype(np.int64)
    pin.vertices = held
    pin.offsets = sim.positions[held] - sim.positions[pin.vertex]
    if clamp_weight != 1.0:
        import dataclasses
        if lod:
            raise ValueError("clamp_weight needs a fixed topology (LOD off)")
        is_held = np.zeros(len(sim.rest_uv), dtype=bool)
        is_held[held] = True
        hv = sim.elements.hinge_vertices
        on_line = is_held[hv[:, :2]].all(axis=1) & (is_held[hv[:, 2]] != is_held[hv[:, 3]])
        weight = sim.elements.hinge_weight.copy()
        weight[on_line] *= clamp_weight
        sim.elements = dataclasses.replace(sim.elements, hinge_weight=weight)
    root_uv = np.zeros(2)
    root_uv[axis], root_uv[1 - axis] = CLAMP, 0.5 * WIDTH
    tip_uv = root_uv.copy()
    tip_uv[axis] = CLAMP + overhang
    history = []
    for k in range(max_steps):
        sim.step()
        history.append(sim.sample([tip_uv])[0].copy())
        if k > 20 and np.linalg.norm(history[-1] - history[-11]) < tolerance:
            break
    else:
        raise RuntimeError(f"not at rest after {max_steps} steps")
    root, tip = sim.sample([root_uv, tip_uv])
    chord = tip - root
    angle = float(np.arctan2(-chord[2], np.hypot(chord[0], chord[1])))
    return angle, sim


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--levels", type=int, nargs="+", default=[4, 5, 6, 7, 8])
    parser.add_argument("--lc", type=float, nargs="+", default=[0.5, 1.0, 2.0, 3.0])
    parser.add_argument("--along", nargs="+", default=["u", "v"])
    parser.add_argument("--lod", nargs="+", default=["off", "on"])
    parser.add_argument("--clamp-weight", type=float, default=1.0,
                        help="factor on the clamp line's hinge weights (LOD off)")
    args = parser.parse_args(argv)
    print("level along lod   l/c  angle°  elastica°  B/k_b  steps  s")
    for lod in args.lod:
        for along in args.along:
            for level in args.levels:
                for lc in args.lc:
                    start = time.perf_counter()
                    angle, sim = simulate(level, lc, along, lod == "on",
                                          clamp_weight=args.clamp_weight)
                    ratio = implied_length_ratio(angle)
                    print(f"{level:5d} {along:5s} {lod:3s} {lc:5.2f} {np.degrees(angle):7.3f} "
                          f"{np.degrees(elastica_chord_angle(lc)):9.3f} "
                          f"{(lc / ratio) ** 3:6.4f} {sim.step_count:6d} "
                          f"{time.perf_counter() - start:5.1f}", flush=True)


if __name__ == "__main__":
    main()
