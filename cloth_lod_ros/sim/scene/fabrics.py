"""Fabric presets (``material.preset``) and the bending rigidity from a ruler.

A preset fills the material fields a published measurement gives for one real fabric:
areal density (kg/m²), stretch and shear stiffness (N/m) and the bending rigidity
B (N·m); a field given explicitly in the same ``material`` mapping wins over the
preset.  Damping and ``air_drag`` are no part of a preset (none of the sources measures
them in this model's terms): they keep their own values.

Sources (docs/scenes.md, "Fabric presets", has the table and every conversion):

* **[W]** Wang, O'Brien & Ramamoorthi, "Data-driven elastic models for cloth: modeling
  and measurement", ACM Trans. Graph. 30(4), 2011 - ten fabrics measured, published as
  material files for the ARCSim simulator.  Density is kg/m² as published.  Stretch
  and shear: the zero-strain sample ``s = (s_uu, s_uv, s_vv, s_sh)`` of that model,
  whose energy per rest area is ``s_uu ε_uu² + s_vv ε_vv² + 2 s_sh ε_uv² + ...`` in
  Green strain (ARCSim doubles the samples and uses ``½ k ε²``), so this model's
  ``½ k_s (|w|−1)²`` and ``½ k_sh (w_u·w_v)²`` match at small strain with
  ``k_s = 2 s`` (mean of the u and v values: one stretch stiffness here) and
  ``k_sh = s_sh``.  Bending: the lowest-curvature sample ``k`` of the discrete hinge
  energy ``k l² θ² / (8 (A₁ + A₂))`` (Bridson et al. 2003's scaling, ARCSim's form),
  mean over its three directions.  That hinge energy equals ``½ B κ²`` per area with
  B between k/8 (first-order account of an equilateral mesh) and k/4 (the same mesh
  placed on a cylinder, where chords fold the hinges along the bend too): we use
  B = k/6, uncertain by a factor 1.5 either way.
* **[M]** Matsudaira, Masuda, Wada & Yokura, "Shape factor of flared skirts compared
  with that of circular fabrics", J. Textile Eng. 61(6):69-73, 2015, Table 1: KES-FB2
  bending rigidity B (gf·cm²/cm) and weight W (mg/cm²).  1 gf·cm²/cm =
  9.80665e-3 N × 1e-4 m² / 1e-2 m = 9.80665e-5 N·m; 1 mg/cm² = 0.01 kg/m².  KES
  measures no linear stretch or shear stiffness in N/m, so these presets take
  stretch and shear from the [W] woven of the nearest fibre and weight (stated per
  preset).

ASTM D1388 (Peirce's cantilever): push a strip over a table edge until its tip touches
a line 41.5° below the horizontal through the edge; the overhang is twice the bending
length c, and ``B = w c³`` with ``w`` the weight per area (N/m²).  The 41.5° is where
the heavy elastica's chord from clamp to tip points at l = 2c
(:func:`cloth_lod_ros.tools.cantilever.elastica_chord_angle`).
"""

from __future__ import annotations

from dataclasses import dataclass

from .bounded_yaml import SceneError
from .bounded_yaml import shorten as _show

__all__ = ["Fabric", "FABRICS", "PRESET_FIELDS", "apply_preset", "fabric_names",
           "rigidity_from_overhang", "ASTM_D1388_ANGLE_DEG", "STANDARD_GRAVITY"]

#: m/s², the conventional g (KES's gram-force is defined with it).
STANDARD_GRAVITY = 9.80665
#: Angle below the horizontal of the ASTM D1388 line (degrees).
ASTM_D1388_ANGLE_DEG = 41.5

_GF_CM2_PER_CM = 9.80665e-5     # N·m per gf·cm²/cm
_MG_PER_CM2 = 0.01              # kg/m² per mg/cm²


@dataclass(frozen=True)
class Fabric:
    """One preset: the material fields it fills (SI) and where each comes from."""

    name: str
    description: str
    density: float              # kg/m²
    stretch_stiffness: float    # N/m
    shear_stiffness: float      # N/m
    bend_stiffness: float       # N·m, the continuum bending rigidity B
    source: str                 # short citation key(s): [W] / [M] and the sample


def _sig2(value: float) -> float:
    return float(f"{value:.2g}")


def _wang(name, description, sample, density, s_uu, s_vv, s_sh, bend_samples):
    """A [W] fabric from its published zero-strain stretch sample and its three
    lowest-curvature bending samples (N·m, one per direction)."""
    # Two significant digits: the fit behind each sample is no more precise.
    return Fabric(name, description, density, _sig2(s_uu + s_vv), _sig2(s_sh),
                  _sig2(sum(bend_samples) / len(bend_samples) / 6.0), f"[W] {sample}")


def _kes(name, description, reference, b_kes, w_kes, membrane: Fabric, note):
    """An [M] fabric: KES B (gf·cm²/cm) and W (mg/cm²); stretch and shear of the
    [W] fabric ``membrane``."""
    return Fabric(name, description, round(w_kes * _MG_PER_CM2, 4),
                  membrane.stretch_stiffness, membrane.shear_stiffness,
                  float(f"{b_kes * _GF_CM2_PER_CM:.3g}"),
                  f"[M] {reference}; stretch and shear: {membrane.source} ({note})")


_DENIM = _wang("denim", "11 oz denim, jeans (99 % cotton, 1 % spandex)", "11oz-black-denim",
               0.324, 205.352005, 1013.88629, 53.387184,
               (64.196457e-6, 73.384567e-6, 96.951576e-6))
_COTTON_POLY = _wang("cotton_polyester", "woven trouser fabric (65 % cotton, 35 % polyester)",
                     "royal-target", 0.220, 2016.55456, 2034.97644, 104.759674,
                     (125.409805e-6, 107.997696e-6, 125.409805e-6))
_POLY_TABLECLOTH = _wang("polyester_tablecloth", "tablecloth (100 % polyester)",
                         "white-dots-on-blk", 0.128, 2002.08618, 2027.48559, 19.189022,
                         (51.713814e-6, 40.659470e-6, 31.282822e-6))
_POLY_JACKET = _wang("polyester_jacket", "light jacket fabric (100 % polyester)",
                     "tango-red-jet-set", 0.113, 43.067627, 171.424835, 14.314700,
                     (14.293814e-6, 21.951700e-6, 20.345654e-6))
_KNIT = _wang("interlock_knit", "T-shirt interlock knit (60 % cotton, 40 % polyester)",
              "gray-interlock", 0.187, 16.593832, 34.477123, 36.860302,
              (23.191698e-6, 24.749964e-6, 14.267624e-6))

#: The presets by name.
FABRICS: dict[str, Fabric] = {f.name: f for f in (
    _kes("cotton", "cotton broadcloth, plain weave (shirting)", "fabric A, cotton broad",
         0.118, 12.38, _COTTON_POLY, "the woven with the most cotton in [W]"),
    _DENIM,
    _kes("wool", "wool tropical, plain weave (summer suiting)", "fabric B, wool tropical",
         0.067, 16.29, _COTTON_POLY, "[W] has no wool: a stand-in, its cotton-rich woven"),
    _kes("polyester", "polyester faille", "fabric F, polyester faille", 0.019, 10.43,
         _POLY_TABLECLOTH, "a 100 % polyester woven of [W]"),
    _COTTON_POLY,
    _POLY_JACKET,
    _KNIT,
)}

#: The material fields a preset fills.
PRESET_FIELDS = ("density", "stretch_stiffness", "shear_stiffness", "bend_stiffness")


def fabric_names() -> tuple[str, ...]:
    return tuple(FABRICS)


def apply_preset(material, path: str = "material"):
    """The raw ``material`` mapping with its ``preset``'s fields filled in where the
    mapping does not give them (the mapping's own values win).

    Raises:
        SceneError: an unknown preset (the message lists the known ones).
    """
    if not isinstance(material, dict) or material.get("preset") in (None, ""):
        return material
    name = material["preset"]
    if not isinstance(name, str) or name not in FABRICS:
        raise SceneError(f"field '{path}.preset' = {_show(name)} is not a known fabric; "
                         f"known: {', '.join(FABRICS)}")
    fabric = FABRICS[name]
    out = {key: getattr(fabric, key) for key in PRESET_FIELDS}
    out.update(material)
    return out


def rigidity_from_overhang(overhang: float, mass_per_area: float,
                           gravity: float = STANDARD_GRAVITY) -> float:
    """Bending rigidity B (N·m) from an ASTM D1388 cantilever reading.

    Args:
        overhang: m the strip sticks out over the edge when its tip touches the line
            41.5° below the horizontal (the bending length is half of it).
        mass_per_area: the fabric's areal density, kg/m² (weigh a known area).
        gravity: m/s².

    Returns ``B = m g (overhang/2)³`` (Peirce 1930; ASTM D1388, option A).
    """
    if not (overhang > 0.0 and mass_per_area > 0.0 and gravity > 0.0):
        raise ValueError("overhang, mass_per_area and gravity must be > 0")
    return mass_per_area * gravity * (0.5 * overhang) ** 3
