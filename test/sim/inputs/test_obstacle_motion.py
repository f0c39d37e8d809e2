"""Kinematic obstacles: moved by scripted waypoints or live targets, their
velocity enters contact and friction (design §3, "Moving obstacles").

Behaviour, not snapshots: a tray carries a cloth by friction (or lets it slide
at a − μg), a cloth landing on a tray in uniform motion does what it does on a
still one (Galilean invariance), a turntable turns the cloth with it, a box
sweeping a table pushes the cloth without letting any particle into it, and an
obstacle that is kinematic but does not move changes nothing, bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cloth_lod_ros.sim import ClothSim
from cloth_lod_ros.sim.scene.config import SceneError, scene_from_dict, scene_to_dict
from cloth_lod_ros.sim.contact.contacts import ContactSet, find_contacts, penetrations
from cloth_lod_ros.sim.contact.obstacles import Plane
from cloth_lod_ros.messages.frames import FrameBuilder

H = 1.0 / 60.0
G = 9.81


def _scene(obstacles, *, level=3, size=0.5, origin=(-0.25, -0.25, 0.004), duration=1.0,
           **sections):
    data = dict(name="kinematic",
                cloth=dict(width=size, height=size, base_blocks=[2, 2], level=level,
                           origin=list(origin)),
                air=dict(density=0.0),          # air is relative to the ground
                obstacles=obstacles,
                simulation=dict(time_step=H, duration=duration))
    data.update(sections)
    return scene_from_dict(data)


def _tray(mu, path, **kw):
    """A box tray (top face at z = 0 when its centre is at z = -0.05) moving
    along ``path`` ``[(t, x), ...]``."""
    return dict(type="box", name="tray", centre=[0.0, 0.0, -0.05],
                half_extents=[1.5, 1.5, 0.05], friction=mu, max_speed=100.0,
                waypoints=[[float(t), float(x), 0.0, -0.05] for t, x in path], **kw)


def _accelerating(a, t_acc, duration):
    """Waypoints at every frame of x = a t²/2 until ``t_acc``, then uniform."""
    t = np.arange(int(round(duration / H)) + 1) * H
    x = np.where(t < t_acc, 0.5 * a * t ** 2, 0.5 * a * t_acc ** 2 + a * t_acc * (t - t_acc))
    return list(zip(t, x))


def test_a_tray_carries_a_cloth_by_static_friction():
    """μ = 1, a = 2 m/s² < μg: the cloth sticks, its velocity is the tray's."""
    a, t_acc = 2.0, 0.5
    sim = ClothSim(_scene([_tray(1.0, _accelerating(a, t_acc, 1.0))]))
    for _ in range(60):
        sim.step()
        t = sim.time
        # The tray's velocity over the step just taken (constant within a step).
        tray_v = a * min(t - 0.5 * H, t_acc) if t - H < t_acc else a * t_acc
        if t - H < t_acc < t:
            continue                        # the step that stops accelerating
        np.testing.assert_allclose(sim.velocities[:, 0], tray_v, atol=1e-6 + 1e-3 * tray_v)
        tray_x = sim.obstacle("tray").position[0]
        # Carried rigidly: every particle where it started, relative to the tray.
        np.testing.assert_allclose(sim.positions[:, 0] - tray_x, sim.rest_uv[:, 0] - 0.25,
                                   atol=1e-4)
    assert sim.velocities[:, 0].mean() == pytest.approx(a * t_acc, rel=1e-3)


def test_a_cloth_slides_on_a_tray_that_accelerates_harder_than_friction_allows():
    """μ = 0.1, a = 5 m/s²: kinetic friction accelerates the cloth at μg, so
    relative to the tray it accelerates backwards at a − μg."""
    mu, a = 0.1, 5.0
    sim = ClothSim(_scene([_tray(mu, _accelerating(a, 1.0, 0.6))]))
    times, velocity = [], []
    for _ in range(30):
        sim.step()
        times.append(sim.time)
        velocity.append(sim.velocities[:, 0].mean())
    slope = np.polyfit(times[3:], velocity[3:], 1)[0]
    assert slope == pytest.approx(mu * G, rel=0.03)
    relative = a - slope
    assert relative == pytest.approx(a - mu * G, rel=0.01)
    # Still on the tray's top, no bounce off it.
    np.testing.assert_allclose(sim.positions[:, 2], 0.004, atol=1e-6)


def test_landing_on_a_tray_in_uniform_motion_is_landing_on_a_still_one():
    """Galilean invariance: a cloth dropped with the tray's velocity onto the
    moving tray lands, settles and slides relative to it exactly as onto the
    still tray (to rounding).  Friction acts on the relative velocity, the
    landing on the relative normal velocity."""
    V = np.array([0.7, -0.3, 0.0])
    runs = []
    for moving in (False, True):
        tray = _tray(0.3, [])
        if moving:
            tray["waypoints"] = [[0.0, 0.0, 0.0, -0.05], [1.0, V[0], V[1], -0.05]]
        # Dropped from 3 cm at 0.5 m/s, sliding at 0.2 m/s relative to the tray.
        sim = ClothSim(_scene([tray], origin=(-0.25, -0.25, 0.03)))
        sim.state.velocities[:] = (V if moving else 0.0) + np.array([0.2, 0.0, -0.5])
        relative = []
        for _ in range(45):
            sim.step()
            shift = V * sim.time if moving else 0.0
            relative.append(sim.positions - shift)
        runs.append(np.array(relative))
    np.testing.assert_allclose(runs[1], runs[0], atol=1e-6)
    # The cloth did land and slide (the test is not about a cloth in the air).
    assert runs[0][-1][:, 2].max() < 0.0045
    assert runs[0][-1][:, 0].mean() > 0.005


def test_a_turntable_turns_the_cloth_with_it():
    """A disc spun up about its axis (scripted orientation waypoints) carries a
    cloth lying on it: the cloth's velocity becomes ω × r, the velocity field of
    the turning surface."""
    alpha, duration = 2.0, 0.8                              # rad/s², s
    t = np.arange(int(round(duration / H)) + 1) * H
    angle = 0.5 * alpha * t ** 2
    rows = [[float(ti), 0.0, 0.0, -0.01, *Rotation.from_rotvec([0, 0, th]).as_quat()]
            for ti, th in zip(t, angle)]
    disc = dict(type="disc", name="turntable", centre=[0.0, 0.0, -0.01], radius=0.5,
                half_height=0.01, friction=1.0, waypoints=rows)
    sim = ClothSim(_scene([disc], size=0.4, origin=(-0.2, -0.2, 0.004)))
    for _ in range(len(t) - 1):
        sim.step()
    omega = alpha * (duration - 0.5 * H)                    # over the last step
    expected = np.cross([0.0, 0.0, omega], sim.positions - [0.0, 0.0, 0.0])
    np.testing.assert_allclose(sim.velocities[:, :2], expected[:, :2],
                               atol=0.02 * omega * 0.3)
    # The disc's pose is where the script put it.
    _, q = sim.obstacle_pose("turntable")
    assert Rotation.from_quat(q).magnitude() == pytest.approx(angle[-1], abs=1e-9)


def _sweep_scene(**kw):
    return _scene([dict(type="plane", name="table", friction=0.4),
                   dict(type="box", name="pusher", centre=[-0.35, 0.0, 0.03],
                        half_extents=[0.05, 0.4, 0.08], friction=0.3,
                        waypoints=[[0.1, -0.35, 0.0, 0.03], [1.6, 0.25, 0.0, 0.03]])],
                  contact=dict(friction_rounds=40), duration=1.6, **kw)


@pytest.mark.parametrize("lod", [False, True])
def test_a_box_sweeping_a_table_pushes_the_cloth_and_never_contains_a_particle(lod):
    scene = _sweep_scene(lod=dict(enabled=lod, initial_level=1))
    sim = ClothSim(scene)
    thickness = scene.contact.thickness
    start = sim.positions[:, 0].mean()
    for _ in range(96):
        sim.step()
        box = sim.obstacles[1]
        phi = box.distance(sim.positions)[0]
        assert phi.min() > 0.0, (sim.time, phi.min())
        assert sim.obstacles[0].distance(sim.positions)[0].min() > -0.25 * thickness
    # The box moved 0.6 m and took the cloth (its near edge started 0.15 m
    # ahead of the box's face) along.
    assert sim.obstacle("pusher").position[0] == pytest.approx(0.25)
    assert sim.positions[:, 0].mean() - start > 0.3
    assert sim.positions[:, 0].min() > 0.25 + 0.05


def test_a_kinematic_obstacle_that_does_not_move_changes_nothing():
    """Scripted to stay where it is, an obstacle is kinematic (its contacts
    carry a surface velocity, zero) and the run is bit-identical to the static one."""
    runs = []
    for scripted in (False, True):
        ball = dict(type="sphere", name="ball", centre=[0.0, 0.0, 0.0], radius=0.2,
                    friction=0.3)
        if scripted:
            ball["waypoints"] = [[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]
        sim = ClothSim(_scene([ball, dict(type="plane", name="floor",
                                          centre=[0, 0, -0.2])],
                              origin=(-0.25, -0.25, 0.25), lod=dict(enabled=True,
                                                                    initial_level=1)))
        for _ in range(30):
            sim.step()
        assert sim.obstacle("ball").kinematic == scripted
        runs.append((sim.positions.copy(), sim.velocities.copy(), sim.triangles.copy()))
    for a, b in zip(*runs):
        assert np.array_equal(a, b)


def test_live_targets_are_followed_at_the_speed_limit():
    sim = ClothSim(_sweep_scene())
    box = sim.obstacle("pusher")
    box.max_speed = 0.5
    start = box.position.copy()
    sim.set_obstacle_target("pusher", start + [0.0, 0.3, 0.0],
                            Rotation.from_rotvec([0, 0, 0.4]).as_quat())
    assert box.kinematic and len(box.waypoints) == 0      # a live command replaces the script
    sim.step()
    assert np.linalg.norm(box.position - start) == pytest.approx(0.5 * H)
    assert box.jumps == 1
    for _ in range(60):
        sim.step()
    np.testing.assert_allclose(box.position, start + [0.0, 0.3, 0.0], atol=1e-12)
    assert Rotation.from_quat(sim.obstacle_pose("pusher")[1]).magnitude() == \
        pytest.approx(0.4)
    # The geometry and the markers follow the pose.
    np.testing.assert_allclose(sim.obstacles[1].centre, box.position)
    cfg = sim.obstacle_configs()[1]
    np.testing.assert_allclose(cfg.centre, box.position)
    np.testing.assert_allclose(np.abs(cfg.orientation @ sim.obstacle_pose("pusher")[1]), 1.0)
    with pytest.raises(ValueError):
        sim.set_obstacle_target("pusher", [np.nan, 0, 0])
    with pytest.raises(ValueError):
        sim.set_obstacle_target("pusher", [0, 0, 0], [0, 0, 0, 0])
    with pytest.raises(KeyError):
        sim.set_obstacle_target("nobody", [0, 0, 0])
    np.testing.assert_allclose(box.command_position, start + [0.0, 0.3, 0.0])


def test_markers_follow_the_obstacle():
    from cloth_lod_ros.messages.markers import obstacle_markers
    sim = ClothSim(_sweep_scene())
    before = obstacle_markers(sim.obstacle_configs(), "world")[1]
    for _ in range(30):
        sim.step()
    after = obstacle_markers(sim.obstacle_configs(), "world")[1]
    assert after.position[0] - before.position[0] == pytest.approx(
        sim.obstacle("pusher").position[0] + 0.35)
    assert after.position[0] > before.position[0] + 0.1
    # The frame builder draws them where they are.
    frames = FrameBuilder().build(sim, (0, 0))
    assert isinstance(frames["cloth/markers"], bytes)


def test_surface_velocity_enters_detection_and_penetration_distances():
    moving = Plane("floor", 0.5, np.zeros(3), np.array([0.0, 0.0, 1.0]),
                   velocity=np.array([0.1, 0.0, 1.0]), angular_velocity=np.zeros(3))
    x = np.array([[0.0, 0.0, 0.02], [0.0, 0.0, 0.2]])
    still = np.zeros_like(x)
    # A still particle 2 cm above a floor rising at 1 m/s is caught this step.
    cs = find_contacts([moving], x, 0.004, velocities=still, h=0.02)
    assert list(cs.indices) == [0]
    np.testing.assert_allclose(cs.velocity, [[0.1, 0.0, 1.0]])
    assert cs.normal_speed() == pytest.approx([1.0])
    static = dataclass_copy = Plane("floor", 0.5, np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert len(find_contacts([static], x, 0.004, velocities=still, h=0.02)) == 0
    assert find_contacts([dataclass_copy], x, 0.004).velocity is None
    # Found inside at the end of a step: the distance is to where the plane was.
    end = np.array([[0.0, 0.0, 0.001], [0.0, 0.0, 0.2]])
    pen = penetrations([moving], x, end, 0.004, h=0.02)
    assert list(pen.indices) == [0]
    assert pen.distance[0] == pytest.approx(0.02 + 0.02 - 0.004)


def test_contact_sets_keep_velocities_through_subset_and_union():
    a = ContactSet(np.array([0, 1]), np.tile([0.0, 0, 1], (2, 1)), np.zeros(2), np.ones(2))
    b = ContactSet(np.array([1, 2]), np.tile([1.0, 0, 0], (2, 1)), np.zeros(2), np.ones(2),
                   velocity=np.array([[1.0, 0, 0], [2.0, 0, 0]]))
    u = a.union(b)
    assert list(u.indices) == [0, 1, 2]
    np.testing.assert_array_equal(u.velocity, [[0, 0, 0], [1, 0, 0], [2, 0, 0]])
    assert a.union(a).velocity is None
    np.testing.assert_array_equal(u.subset(np.array([False, True, True])).velocity,
                                  [[1, 0, 0], [2, 0, 0]])


# -- configuration ------------------------------------------------------------------

def _with_box(**fields):
    box = dict(type="box", name="pusher", centre=[0, 0, 0.1], half_extents=[0.1, 0.1, 0.1])
    box.update(fields)
    return dict(cloth=dict(width=1.0, height=1.0, base_blocks=[1, 1]),
                simulation=dict(time_step=H, duration=1.0), obstacles=[box])


@pytest.mark.parametrize("fields, message", [
    (dict(waypoints=[[0, 0, 0]]), "obstacles[0].waypoints[0]"),
    (dict(waypoints=[[0, 0, 0, 0, 0]]), "obstacles[0].waypoints[0]"),
    (dict(waypoints=[[0, 0, 0, 0], [1, 0, 0, 0, 0, 0, 0, 1]]), "obstacles[0].waypoints[1]"),
    (dict(waypoints=[[0, 0, 0, 0, 0, 0, 0, 0]]), "obstacles[0].waypoints[0]"),
    (dict(waypoints=[[1, 0, 0, 0], [0.5, 0, 0, 0]]), "obstacles[0].waypoints"),
    (dict(waypoints=[[0, float("nan"), 0, 0]]), "obstacles[0].waypoints[0][1]"),
    (dict(waypoints="fast"), "obstacles[0].waypoints"),
    (dict(max_speed=0.0), "obstacles[0].max_speed"),
    (dict(max_angular_speed=-1.0), "obstacles[0].max_angular_speed"),
    (dict(name="my box"), "obstacles[0].name"),
    (dict(name="1box"), "obstacles[0].name"),
])
def test_bad_kinematics_are_refused_naming_the_field(fields, message):
    with pytest.raises(SceneError, match=message.replace("[", r"\[").replace("]", r"\]")):
        scene_from_dict(_with_box(**fields))


def test_pose_waypoints_are_normalised_and_round_trip():
    scene = scene_from_dict(_with_box(waypoints=[[0, 0, 0, 0.1, 0, 0, 0, 2.0],
                                                 [1, 0.5, 0, 0.1, 0, 0, 1, 1]]))
    rows = scene.obstacles[0].waypoints
    assert rows[0][4:] == (0.0, 0.0, 0.0, 1.0)
    assert rows[1][4:] == pytest.approx((0, 0, 2 ** -0.5, 2 ** -0.5))
    assert scene_from_dict(scene_to_dict(scene)) == scene
    # Between keyframes: linear in position, slerp in orientation.
    sim = ClothSim(scene)
    position, rotation = sim.obstacle("pusher").target_at(0.5)
    np.testing.assert_allclose(position, [0.25, 0, 0.1])
    assert rotation.magnitude() == pytest.approx(np.pi / 4)
