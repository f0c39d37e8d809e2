"""Peirce's cantilever tool (issue 32's measurement) against closed forms.

The heavy elastica solved by ``tools/cantilever`` must reduce to linear beam
theory for a small overhang (a uniformly loaded cantilever's tip slope
q l³/(6 B)) and give Peirce's 41.5° chord at l = 2c (ASTM D1388); the
inversion of the chord angle must return the l/c it came from.
"""

import math

import pytest

from cloth_lod_ros.tools import cantilever


def test_a_short_overhang_droops_as_a_linear_beam():
    """Chord angle of a uniformly loaded cantilever, small deflection:
    tip deflection q l⁴/(8B), so tan(chord) = (l/c)³/8 with c³ = B/w."""
    for lc in (0.2, 0.3):
        expected = math.atan(lc ** 3 / 8.0)                    # rad
        assert cantilever.elastica_chord_angle(lc) == pytest.approx(expected, rel=2e-3)


def test_peirce_chord_angle_at_twice_the_bending_length():
    assert math.degrees(cantilever.elastica_chord_angle(2.0)) == pytest.approx(41.5, abs=0.1)


@pytest.mark.parametrize("lc", [0.5, 1.0, 2.0, 3.0])
def test_the_chord_angle_inverts_to_its_length_ratio(lc):
    angle = cantilever.elastica_chord_angle(lc)
    assert cantilever.implied_length_ratio(angle) == pytest.approx(lc, rel=1e-6)
