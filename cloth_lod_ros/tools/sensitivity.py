"""How far a scene's motion amplifies a nanometre: the floor under any
"error against the converged motion".

A cloth dropped centred on a ball, or piling on a floor, buckles into folds
whose number and direction are chosen by whatever breaks the symmetry first.
Two runs of the same model that differ by rounding (another summation order,
another CPU, a different mesh path to the same state) can choose differently,
and their distance is then not an error of either: it is the scene's own
sensitivity.  Measured here by running the scene once as given and again with
every particle's start position moved by ``size`` (default 1 nm, a million
times below any modelled length) in a seeded random direction, and reporting
the RMS and largest distance of the two over a 21 × 21 grid of material
points, as a fraction of the cloth's larger side.  An error against a
converged reference below this floor cannot be told from it.

    python -m cloth_lod_ros.tools.sensitivity drop_on_sphere --set lod.enabled=false

``cloth-lod bench --contact`` measures the same floor on each scene's
converged reference (:mod:`.bench.contact`).
"""

from __future__ import annotations

import argparse

import numpy as np

__all__ = ["perturb", "sensitivity"]


def perturb(sim, size: float, seed: int = 0) -> None:
    """Move every particle of ``sim`` by ``size`` (m) times a standard normal
    sample per coordinate (``numpy.random.default_rng(seed)``), at rest as it was."""
    rng = np.random.default_rng(seed)
    sim.state.positions[:] += size * rng.standard_normal(sim.state.positions.shape)


def _samples(scene, overrides, times, size, seed):
    from ..sim import ClothSim
    from ..sim.scene.config import load_scene
    from ..sim.mesh.sampling import material_grid
    sim = ClothSim(load_scene(scene, overrides))
    if size:
        perturb(sim, size, seed)
    points = material_grid(sim.scene.cloth.width, sim.scene.cloth.height, 21)
    out = []
    for t in times:
        while sim.time < t - 1e-9:
            sim.step()
        out.append(np.asarray(sim.sample(points)))
    return out, max(sim.scene.cloth.width, sim.scene.cloth.height)


def sensitivity(scene: str, overrides=(), times=(1.0, 2.0, 3.0), size: float = 1e-9,
                seeds=(1,)) -> list[dict]:
    """For each seed, ``{"seed", "rms": [...], "max": [...]}``: the distance
    (fraction of the larger side) at ``times`` (s) between the run as given and
    the run perturbed by ``size`` m (module docstring)."""
    from .reference import point_distances
    base, side = _samples(scene, list(overrides), times, 0.0, 0)
    rows = []
    for seed in seeds:
        other, _ = _samples(scene, list(overrides), times, size, seed)
        d = [point_distances(a, b) for a, b in zip(base, other)]
        rows.append(dict(seed=seed, rms=[float(np.sqrt(np.mean(x ** 2))) / side for x in d],
                         max=[float(x.max()) / side for x in d]))
    return rows


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scene")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--times", type=float, nargs="+", default=[1.0, 2.0, 3.0])
    parser.add_argument("--size", type=float, default=1e-9, help="m (default 1 nm)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    args = parser.parse_args(argv)
    rows = sensitivity(args.scene, args.set, args.times, args.size, args.seeds)
    print(f"{args.scene} {' '.join(args.set)}: start moved by {args.size:g} m")
    for r in rows:
        print(f"  seed {r['seed']}: RMS " + " / ".join(f"{100 * e:.2f} %" for e in r["rms"])
              + " (largest " + " / ".join(f"{100 * e:.1f} %" for e in r["max"])
              + f") at {' / '.join(f'{t:g}' for t in args.times)} s")


if __name__ == "__main__":
    main()
