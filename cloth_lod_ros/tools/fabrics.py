"""Fabric presets and a ruler-and-scale bending rigidity (ASTM D1388).

``python -m cloth_lod_ros.tools.fabrics`` lists the presets (docs/scenes.md has their
sources); ``--overhang L --mass-per-area m`` turns a cantilever reading into B:

1. Cut a strip (ASTM D1388 uses 25 mm × 200 mm), weigh it and divide by its area:
   ``m`` in kg/m².
2. Lay it on a flat table and slide it over the edge until its tip touches a line
   41.5° below the horizontal through the edge (a card cut at that angle).
3. The overhang ``L`` (m) is twice the bending length c; ``B = m g c³`` (N·m).

The 41.5° is the chord angle of the heavy elastica at overhang 2c (Peirce 1930;
:func:`cloth_lod_ros.tools.cantilever.elastica_chord_angle` solves it), so the reading
holds however stiff the fabric is.
"""

from __future__ import annotations

import argparse

from ..sim.scene.fabrics import FABRICS, rigidity_from_overhang

__all__ = ["main", "preset_table"]


def preset_table() -> str:
    lines = [f"{'preset':17s} {'kg/m^2':>7s} {'k_s N/m':>8s} {'k_sh N/m':>8s} "
             f"{'B N*m':>8s}  source"]
    for f in FABRICS.values():
        lines.append(f"{f.name:17s} {f.density:7.4g} {f.stretch_stiffness:8.4g} "
                     f"{f.shear_stiffness:8.4g} {f.bend_stiffness:8.3g}  {f.source}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--overhang", type=float, metavar="L",
                        help="m over the edge when the tip touches the 41.5 deg line")
    parser.add_argument("--mass-per-area", type=float, metavar="M",
                        help="kg/m^2, the fabric's weight per area")
    args = parser.parse_args(argv)
    if args.overhang is None and args.mass_per_area is None:
        print(preset_table())
        return 0
    if args.overhang is None or args.mass_per_area is None:
        parser.error("--overhang and --mass-per-area go together")
    try:
        rigidity = rigidity_from_overhang(args.overhang, args.mass_per_area)
    except ValueError as exc:
        parser.error(str(exc))
    print(f"bending length c = {0.5 * args.overhang:.4g} m, B = {rigidity:.3g} N*m")
    print(f"--set material.density={args.mass_per_area:.4g} "
          f"--set material.bend_stiffness={rigidity:.3g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
