"""bench --local: the uniform front and the factor below it (issue 33)."""

import math

import numpy as np
import pytest

from cloth_lod_ros.tools.bench.local import LOCAL_SCENES, front_cost, markdown, scene_path
from cloth_lod_ros.sim.scene.config import load_scene


def test_front_of_a_power_law_is_the_power_law():
    """Uniform runs on cost = a e^-p: the front returns it between and beyond them."""
    a, p = 2.0, 1.5
    runs = [(a * e ** -p, e) for e in (0.3, 0.1, 0.03)]
    for e in (0.2, 0.05, 0.01, 1.0):
        assert front_cost(runs, e) == pytest.approx(a * e ** -p, rel=1e-12)


def test_a_dominated_uniform_run_is_not_on_the_front():
    """A dearer run that is also less accurate (a finer level whose triangles lie
    across the reference's) does not bend the front."""
    runs = [(1.0, 0.3), (3.0, 0.03), (20.0, 0.06)]
    assert front_cost(runs, 0.1) == pytest.approx(front_cost(runs[:2], 0.1), rel=1e-12)
    assert math.isnan(front_cost(runs[:1], 0.1))


def test_local_scenes_are_large_and_fine_enough():
    """The issue's sizes: at least 2 m of cloth on an 8 x 8 base, maximum level >= 6."""
    for name in LOCAL_SCENES:
        scene = load_scene(str(scene_path(name)))
        assert max(scene.cloth.width, scene.cloth.height) >= 2.0
        assert tuple(scene.cloth.base_blocks) == (8, 8) and scene.cloth.level >= 6


def test_table_names_each_scenes_reference_and_factor():
    rows = [dict(scene="s", label="uniform L4", kind="uniform", level=4, error=0.003, cost=1.0,
                 triangles_mean=10, front_cost=None, factor=None),
            dict(scene="s", label="detail, max L6", kind="adaptive", level=6, error=0.001,
                 cost=0.5, triangles_mean=5, front_cost=2.0, factor=4.0)]
    text = markdown(dict(rows=rows, repeats=1, duration=1.0,
                         references={"s": dict(level=7, tolerance=1e-4,
                                               own_error=dict(mesh=0.0006))}))
    assert "uniform L7" in text and "mesh 0.060 %" in text and "| 4.00 |" in text
