"""The node's input judging, queue and health levels, in-process (no ROS graph)."""

import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cloth_lod_ros.ros.inputs import (ERROR, OK, POSE_REJECTIONS, WARN, InputQueue, PoseLimits,
                                      health, judge_pose)
from cloth_lod_ros.sim.integrate.state import StepStats

LIMITS = PoseLimits("world", 1.0, (-2.0, -2.0, -2.0), (2.0, 2.0, 2.0))
NOW = 1000.0


def judge(position=(0.1, 0.2, 0.3), orientation=(0, 0, 0, 1), frame="world", sec=1000,
          nanosec=0, now=NOW, limits=LIMITS):
    return judge_pose(frame, position, orientation, sec, nanosec, now, limits)


def test_a_good_pose_is_accepted_with_a_unit_quaternion():
    reason, p, q = judge(orientation=(0, 0, 0, 5.0))
    assert reason is None
    np.testing.assert_array_equal(p, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(q, [0, 0, 0, 1])


@pytest.mark.parametrize("kwargs, reason", [
    (dict(frame="map"), "frame"),
    (dict(position=(np.nan, 0, 0)), "not_finite"),
    (dict(orientation=(0, np.inf, 0, 1)), "not_finite"),
    (dict(orientation=(0, 0, 0, 0)), "orientation"),
    (dict(sec=-5), "bad_stamp"),
    (dict(nanosec=1_000_000_000), "bad_stamp"),
    (dict(sec=990), "stale"),
    (dict(sec=1010), "future"),
    (dict(position=(1e6, 0, 0)), "workspace"),
    (dict(position=(0, 0, -2.5)), "workspace"),
])
def test_each_kind_of_bad_pose_is_rejected_with_its_reason(kwargs, reason):
    assert judge(**kwargs)[0] == reason
    assert reason in POSE_REJECTIONS


def test_an_overflowing_quaternion_norm_is_normalised_not_fatal():
    """(1e200, 1e200, 0, 0) is finite, but its norm overflows: it used to become a
    zero quaternion that scipy refused with an exception that ended the node."""
    reason, _, q = judge(orientation=(1e200, 1e200, 0.0, 0.0))
    assert reason is None
    np.testing.assert_allclose(q, [2 ** -0.5, 2 ** -0.5, 0, 0])


def test_stamp_zero_means_now_and_a_zero_timeout_does_not_judge_stamps():
    assert judge(sec=0, nanosec=0)[0] is None
    lenient = PoseLimits("world", 0.0, LIMITS.workspace_min, LIMITS.workspace_max)
    assert judge(sec=1, limits=lenient)[0] is None
    assert judge(sec=10**9, limits=lenient)[0] is None


finite = st.floats(allow_nan=True, allow_infinity=True, width=64)


@settings(max_examples=400, deadline=None)
@given(position=st.lists(finite, min_size=3, max_size=3),
       orientation=st.lists(finite, min_size=4, max_size=4),
       frame=st.sampled_from(["world", "", "map", "world\x00"]),
       sec=st.integers(-2**31, 2**31 - 1), nanosec=st.integers(0, 2**32 - 1))
def test_any_pose_is_either_rejected_with_a_reason_or_usable(position, orientation, frame, sec,
                                                           nanosec):
    reason, p, q = judge(position, orientation, frame, sec, nanosec)
    if reason is not None:
        assert reason in POSE_REJECTIONS and p is None and q is None
        return
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(q))
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    assert np.all(p >= LIMITS.workspace_min) and np.all(p <= LIMITS.workspace_max)


def test_the_queue_keeps_the_newest_target_per_grasp_in_arrival_order():
    queue = InputQueue()
    queue.put_target("a", np.zeros(3), np.array([0, 0, 0, 1.0]))
    queue.put_command("close", "b", True)
    queue.put_target("a", np.ones(3), np.array([0, 0, 0, 1.0]))    # replaces the first
    queue.put_command("reset")
    items = queue.take()
    assert [i[0] for i in items] == ["close", "target", "reset"]
    np.testing.assert_array_equal(items[1][2], np.ones(3))
    assert queue.take() == []


def test_obstacle_targets_are_coalesced_per_obstacle_apart_from_grasps():
    queue = InputQueue()
    q = np.array([0, 0, 0, 1.0])
    queue.put_target("a", np.zeros(3), q, "obstacle_target")
    queue.put_target("a", np.full(3, 2.0), q)                         # grasp "a"
    queue.put_target("a", np.ones(3), q, "obstacle_target")           # replaces obstacle "a"
    items = queue.take()
    assert [(i[0], i[1]) for i in items] == [("target", "a"), ("obstacle_target", "a")]
    np.testing.assert_array_equal(items[0][2], np.full(3, 2.0))
    np.testing.assert_array_equal(items[1][2], np.ones(3))


def test_a_full_queue_refuses_commands_but_keeps_taking_targets():
    queue = InputQueue(max_commands=3)
    assert all(queue.put_command("step") for _ in range(3))
    assert not queue.put_command("step")
    queue.put_target("a", np.zeros(3), np.array([0, 0, 0, 1.0]))
    assert len(queue.take()) == 4


def test_the_queue_loses_nothing_under_concurrent_producers():
    queue = InputQueue(max_commands=100_000)
    taken = []

    def produce(k):
        for i in range(2000):
            queue.put_command("n", k, i)

    threads = [threading.Thread(target=produce, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    while any(t.is_alive() for t in threads):
        taken += queue.take()
    taken += queue.take()
    assert len(taken) == 8000
    for k in range(4):                     # each producer's commands stay in order
        mine = [i for _, kk, i in taken if kk == k]
        assert mine == list(range(2000))


def _stats(**kw):
    base = dict(step_index=0, time=0.0, vertex_count=1, triangle_count=1, pinned_count=0,
                contact_count=0, refines=0, merges=0, triangles_per_level=(1,),
                cg_iterations=1, residual=0.0, converged=True, step_ms=1.0, lod_ms=0.0,
                force_ms=0.0, assembly_ms=0.0, solve_ms=0.0, kinetic_energy=0.0,
                gravity_energy=0.0, stretch_energy=0.0, shear_energy=0.0, bend_energy=0.0,
                max_strain=0.01, max_speed=1.0)
    base.update(kw)
    return StepStats(**base)


@pytest.mark.parametrize("kwargs, level, words", [
    (dict(), OK, "running"),
    (dict(paused=True), OK, "paused"),
    (dict(error="non-finite state"), ERROR, "call cloth/reset"),
    (dict(stats=_stats(max_strain=109.0)), ERROR, "unphysical"),
    (dict(stats=_stats(max_speed=500.0)), ERROR, "unphysical"),
    (dict(stats=_stats(max_strain=0.5)), WARN, "large motion"),
    (dict(stats=_stats(converged=False)), WARN, "did not converge"),
    (dict(real_time_factor=0.17), WARN, "slower than real time"),
    (dict(real_time_factor=0.17, paused=True), OK, "paused"),
    (dict(waiting_for_clock=True), WARN, "/clock"),
    (dict(recording_failed=True), WARN, "recording failed"),
])
def test_health_levels(kwargs, level, words):
    args = dict(error=None, stats=_stats(), strain_warn=0.3, speed_warn=20.0,
                real_time_factor=1.0)
    args.update(kwargs)
    got_level, message = health(**args)
    assert got_level == level and words in message
