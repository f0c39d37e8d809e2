"""``tools/sensitivity``: the floor a scene's own dynamics puts under any error.

Outside truths: the perturbation is the stated size (RMS of a standard normal
sample per coordinate); a run moved by 1 nm whose motion does not amplify it
(a cloth hanging from two corners for a tenth of a second, no contact, no
buckling) stays within the solves' own tolerance of the unmoved run (another
right-hand side takes the iterative solves another way: measured 1 µm RMS,
8 µm at most, on the 1 m cloth), far below the 1 % a buckling scene reaches;
and a zero-size perturbation is the same computation.
"""

import numpy as np
import pytest

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import load_scene
from cloth_lod_ros.tools.sensitivity import perturb, sensitivity


def test_the_perturbation_has_the_stated_size_and_is_seeded():
    sim = ClothSim(load_scene("hang_two_corners", ["lod.enabled=false", "cloth.level=4"]))
    start = sim.state.positions.copy()
    perturb(sim, 1e-9, seed=3)
    moved = sim.state.positions - start
    assert np.sqrt(np.mean(moved ** 2)) == pytest.approx(1e-9, rel=0.1)
    again = ClothSim(load_scene("hang_two_corners", ["lod.enabled=false", "cloth.level=4"]))
    perturb(again, 1e-9, seed=3)
    assert np.array_equal(again.state.positions, sim.state.positions)


def test_a_smooth_motion_does_not_amplify_a_nanometre():
    overrides = ["lod.enabled=false", "cloth.level=3", "self_collision.enabled=false"]
    (row,) = sensitivity("hang_two_corners", overrides, times=(0.05, 0.1), size=1e-9)
    assert all(0.0 < e < 1e-5 for e in row["rms"])          # of the 1 m side: < 10 µm
    assert all(e < 1e-4 for e in row["max"])
    (same,) = sensitivity("hang_two_corners", overrides, times=(0.05,), size=0.0)
    assert same["rms"] == [0.0] and same["max"] == [0.0]
