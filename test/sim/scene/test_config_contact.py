"""Scene validation of obstacles, contact and grasps: bad scenes are refused with a
SceneError naming the dotted field; good ones get defaults and normalised values;
every built-in scene loads and its obstacles build."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from cloth_lod_ros.sim.scene.config import (SceneError, builtin_scene_names, load_scene,
                                            scene_from_dict)
from cloth_lod_ros.sim.contact.obstacles import Box, Cylinder, Plane, Sphere, make_obstacle


def base_scene() -> dict:
    return {
        "cloth": {"width": 1.0, "height": 0.5, "base_blocks": [2, 1]},
        "simulation": {"time_step": 0.01, "duration": 0.1},
        "obstacles": [
            {"type": "plane", "name": "floor", "centre": [0, 0, 0], "normal": [0, 0, 1]},
            {"type": "sphere", "centre": [0, 0, 1], "radius": 0.2, "friction": 0.5},
        ],
        "contact": {"thickness": 0.004, "max_correction_speed": 0.5},
        "grasps": [
            {"name": "left", "uv": [0.0, 0.5], "width": 0.05, "max_speed": 1.0,
             "close_time": 0.1, "open_time": 0.5,
             "waypoints": [[0.1, 0, 0, 1], [0.2, 0, 0, 1.1]]},
            {"name": "right_2", "uv": [1.0, 0.5]},
        ],
    }


def refused(data: dict, field: str) -> str:
    with pytest.raises(SceneError) as info:
        scene_from_dict(data)
    message = str(info.value)
    assert f"'{field}'" in message, message
    return message


def with_change(section: str, index: int | None, **changes) -> dict:
    data = base_scene()
    target = data[section] if index is None else data[section][index]
    for key, value in changes.items():
        if value is _DELETE:
            del target[key]
        else:
            target[key] = value
    return data


_DELETE = object()


def test_base_scene_is_valid():
    scene = scene_from_dict(base_scene())
    assert [o.name for o in scene.obstacles] == ["floor", "sphere1"]
    assert scene.contact.thickness == 0.004
    assert [g.name for g in scene.grasps] == ["left", "right_2"]
    assert scene.grasps[0].waypoints == ((0.1, 0.0, 0.0, 1.0), (0.2, 0.0, 0.0, 1.1))
    assert scene.grasps[1].close_time is None and scene.grasps[1].width == 0.0


# -- obstacles -----------------------------------------------------------------

@pytest.mark.parametrize("index, changes, field", [
    (0, dict(type="torus"), "obstacles[0].type"),
    (0, dict(type=3), "obstacles[0].type"),
    (0, dict(type=_DELETE), "obstacles[0].type"),
    (1, dict(radius=-0.1), "obstacles[1].radius"),
    (1, dict(radius=0.0), "obstacles[1].radius"),
    (0, dict(normal=[0.0, 0.0, 0.0]), "obstacles[0].normal"),
    (0, dict(normal=[0.0, 1.0]), "obstacles[0].normal"),
    (1, dict(axis=[0, 0, 0]), "obstacles[1].axis"),
    (1, dict(type="box", orientation=[0, 0, 0, 0]), "obstacles[1].orientation"),
    (1, dict(type="box", orientation=[0, 0, 1]), "obstacles[1].orientation"),
    (1, dict(type="box", half_extents=[0.1, -0.1, 0.1]), "obstacles[1].half_extents"),
    (1, dict(friction=-0.01), "obstacles[1].friction"),
    (1, dict(friction=float("nan")), "obstacles[1].friction"),
    (1, dict(centre=[0, 0, float("inf")]), "obstacles[1].centre[2]"),
    (1, dict(colour="red"), "obstacles[1].colour"),
    (1, dict(half_height=0.0, type="disc"), "obstacles[1].half_height"),
])
def test_bad_obstacle_is_refused(index, changes, field):
    refused(with_change("obstacles", index, **changes), field)


def test_duplicate_obstacle_names_are_refused():
    data = base_scene()
    data["obstacles"][1]["name"] = "floor"
    refused(data, "obstacles")
    # A given name that collides with another's default name is a duplicate too.
    data = base_scene()
    data["obstacles"][0]["name"] = "sphere1"
    refused(data, "obstacles")


def test_obstacles_must_be_a_list_of_mappings():
    data = base_scene()
    data["obstacles"] = {"type": "plane"}
    refused(data, "obstacles")
    data["obstacles"] = ["plane"]
    refused(data, "obstacles[0]")


def test_default_obstacle_names_are_type_and_index():
    data = base_scene()
    data["obstacles"] = [{"type": "sphere"}, {"type": "box", "name": "table"},
                         {"type": "disc"}, {"type": "plane"}, {"type": "cylinder"},
                         {"type": "box"}]
    names = [o.name for o in scene_from_dict(data).obstacles]
    assert names == ["sphere0", "table", "disc2", "plane3", "cylinder4", "box5"]


@pytest.mark.parametrize("raw, expected", [
    ([0, 0, 2, 0], (0.0, 0.0, 1.0, 0.0)),
    ([1, 1, 1, 1], (0.5, 0.5, 0.5, 0.5)),
    ([0, 0, 0.1, 0.1], (0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5))),
    ([0, 0, 0, 1], (0.0, 0.0, 0.0, 1.0)),
])
def test_quaternion_is_normalised(raw, expected):
    data = base_scene()
    data["obstacles"] = [{"type": "box", "orientation": raw}]
    q = scene_from_dict(data).obstacles[0].orientation
    np.testing.assert_allclose(q, expected, atol=1e-15)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)


def test_directions_are_normalised():
    data = base_scene()
    data["obstacles"] = [{"type": "plane", "normal": [0, 0, 5]},
                         {"type": "cylinder", "axis": [3, 4, 0]}]
    plane, cyl = scene_from_dict(data).obstacles
    np.testing.assert_allclose(plane.normal, (0, 0, 1))
    np.testing.assert_allclose(cyl.axis, (0.6, 0.8, 0), atol=1e-15)


# -- contact -------------------------------------------------------------------

@pytest.mark.parametrize("changes, field", [
    (dict(thickness=0.0), "contact.thickness"),
    (dict(thickness=-0.001), "contact.thickness"),
    (dict(thickness="thin"), "contact.thickness"),
    (dict(max_correction_speed=0.0), "contact.max_correction_speed"),
    (dict(margin=0.1), "contact.margin"),
])
def test_bad_contact_is_refused(changes, field):
    refused(with_change("contact", None, **changes), field)


def test_contact_defaults():
    data = base_scene()
    del data["contact"]
    contact = scene_from_dict(data).contact
    assert contact.thickness > 0 and contact.max_correction_speed > 0


# -- grasps --------------------------------------------------------------------

@pytest.mark.parametrize("index, changes, field", [
    (0, dict(name=_DELETE), "grasps[0].name"),
    (1, dict(uv=_DELETE), "grasps[1].uv"),
    (0, dict(uv=[1.01, 0.0]), "grasps[0].uv"),
    (0, dict(uv=[0.5, -0.001]), "grasps[0].uv"),
    (1, dict(uv=[0.5, 0.6]), "grasps[1].uv"),          # cloth height is 0.5
    (0, dict(uv=[0.5]), "grasps[0].uv"),
    (0, dict(open_time=0.05), "grasps[0].open_time"),   # before close_time 0.1
    (0, dict(open_time=0.1), "grasps[0].open_time"),    # equal is not after
    (0, dict(close_time=-0.1), "grasps[0].close_time"),
    (0, dict(name="left hand"), "grasps[0].name"),
    (0, dict(name="a/b"), "grasps[0].name"),
    (0, dict(name=""), "grasps[0].name"),
    (0, dict(name="grip-1"), "grasps[0].name"),
    (1, dict(name="gr\u00e9ta"), "grasps[1].name"),      # not ASCII: no ROS topic
    (1, dict(name="x\u00b2"), "grasps[1].name"),
    (1, dict(name="ok\n"), "grasps[1].name"),
    (1, dict(name=7), "grasps[1].name"),
    (0, dict(waypoints=[[0.1, 0, 0, 1], [0.1, 0, 0, 2]]), "grasps[0].waypoints"),
    (0, dict(waypoints=[[0.2, 0, 0, 1], [0.1, 0, 0, 2]]), "grasps[0].waypoints"),
    (0, dict(waypoints=[[0.1, 0, 0]]), "grasps[0].waypoints[0]"),
    (0, dict(width=-0.01), "grasps[0].width"),
    (0, dict(max_speed=0.0), "grasps[0].max_speed"),
    (0, dict(max_angular_speed=-1.0), "grasps[0].max_angular_speed"),
    (0, dict(tolerance=0.0), "grasps[0].tolerance"),
    (0, dict(force=3.0), "grasps[0].force"),
])
def test_bad_grasp_is_refused(index, changes, field):
    refused(with_change("grasps", index, **changes), field)


def test_duplicate_grasp_names_are_refused():
    data = base_scene()
    data["grasps"][1]["name"] = "left"
    refused(data, "grasps")


@pytest.mark.parametrize("name", ["left", "L2", "right_hand", "g_0_x"])
def test_ascii_word_grasp_names_are_accepted(name):
    data = base_scene()
    data["grasps"][0]["name"] = name
    assert scene_from_dict(data).grasps[0].name == name


def test_grasp_on_the_cloth_border_and_open_only_is_accepted():
    data = base_scene()
    data["grasps"][0].update(uv=[1.0, 0.0], close_time=None, open_time=0.3)
    data["grasps"][1].update(uv=[0.0, 0.5], width=0.0)
    grasps = scene_from_dict(data).grasps
    assert grasps[0].uv == (1.0, 0.0) and grasps[0].open_time == 0.3


def test_validation_does_not_modify_the_input():
    data = base_scene()
    before = copy.deepcopy(data)
    scene_from_dict(data)
    assert data == before


# -- built-in scenes -----------------------------------------------------------

EXPECTED_CLASS = {"plane": Plane, "sphere": Sphere, "cylinder": Cylinder,
                  "disc": Cylinder, "box": Box}


@pytest.mark.parametrize("name", builtin_scene_names())
def test_builtin_scene_loads_and_its_obstacles_build(name):
    scene = load_scene(name)
    assert scene.name == name
    assert scene.contact.thickness > 0
    probe = np.random.default_rng(0).uniform(-2.0, 2.0, (50, 3))
    names = [o.name for o in scene.obstacles]
    assert len(set(names)) == len(names) and all(names)
    for cfg in scene.obstacles:
        obstacle = make_obstacle(cfg)
        assert isinstance(obstacle, EXPECTED_CLASS[cfg.type])
        assert obstacle.name == cfg.name and obstacle.friction == cfg.friction
        phi, normal = obstacle.distance(probe)
        assert phi.shape == (50,) and np.isfinite(phi).all()
        np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-12)
    for grasp in scene.grasps:
        assert 0.0 <= grasp.uv[0] <= scene.cloth.width
        assert 0.0 <= grasp.uv[1] <= scene.cloth.height


def test_builtin_scenes_include_the_contact_scenes():
    names = set(builtin_scene_names())
    assert {"drop_on_disc", "drop_on_sphere", "table_drape", "grasp_lift"} <= names
    assert any(load_scene(n).obstacles for n in names)


@pytest.mark.parametrize("name", ["1st", "9"])
def test_grasp_name_may_not_start_with_a_digit(name):
    with pytest.raises(SceneError, match=r"grasps\[0\]\.name"):
        scene_from_dict({"cloth": {"width": 1, "height": 1, "base_blocks": [4, 4]},
                         "simulation": {"time_step": 0.01, "duration": 1},
                         "grasps": [{"name": name, "uv": [0, 0]}]})


def test_box_rounding_must_fit_the_box():
    with pytest.raises(SceneError, match=r"obstacles\[0\]\.rounding"):
        scene_from_dict({"cloth": {"width": 1, "height": 1, "base_blocks": [4, 4]},
                         "simulation": {"time_step": 0.01, "duration": 1},
                         "obstacles": [{"type": "box", "half_extents": [0.1, 0.5, 0.5],
                                        "rounding": 0.1}]})
