"""The stepping tick's pacing (cloth_lod_node), on a fake clock: the node is built
in this process (real rclpy, its own context, domain and localhost discovery) and
its tick called directly, with each step costing a chosen amount of fake time."""

import os
import random
import textwrap
import time as _real_time

import pytest

os.environ["ROS_DOMAIN_ID"] = str(random.Random(os.getpid() ^ int(_real_time.time()))
                                  .randint(20, 220))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

import rclpy  # noqa: E402  (after the environment is set)
from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from cloth_lod_ros.ros import node as node_module  # noqa: E402

SCENE = textwrap.dedent("""
    name: pacing_test
    cloth: {width: 0.5, height: 0.5, base_blocks: [2, 2], level: 2, origin: [0, 0, 1]}
    grasps:
      - {name: hand, uv: [0.0, 0.5], close_time: 0.0}
    simulation: {time_step: 0.02, duration: 100.0}
    lod: {enabled: false}
""")
H = 0.02
RATE = 25.0


class FakeClock:
    """Stands for the ``time`` module in the node: the steady clock it paces to."""

    def __init__(self):
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


@pytest.fixture
def paced(tmp_path, monkeypatch):
    """``(node, clock, publishes, cost)``: publishes are ``(fake time, step
    count)`` of every frame the node sends; ``cost["s"]`` is the fake time each
    step takes (s)."""
    clock = FakeClock()
    monkeypatch.setattr(node_module, "time", clock)
    scene = tmp_path / "pacing_test.yaml"
    scene.write_text(SCENE)
    context = Context()
    rclpy.init(context=context)
    node = node_module.ClothLodNode(context=context, parameter_overrides=[
        Parameter("scene", value=str(scene)), Parameter("publish_rate", value=RATE)])
    publishes = []
    monkeypatch.setattr(node, "_publish",
                        lambda: publishes.append((clock.now, node.sim.step_count)))
    cost = {"s": 0.0}
    step = node.sim.step

    def costly_step():
        clock.now += cost["s"]
        return step()

    node.sim.step = costly_step
    yield node, clock, publishes, cost
    node.destroy_node()
    rclpy.shutdown(context=context)


def _behind(node, clock) -> float:
    return (clock.now - node._pace_start) - (node.sim.time - node._sim_start)


def test_slower_than_real_time_steps_on_within_a_tick_and_publishes_on_schedule(paced):
    node, clock, publishes, cost = paced
    cost["s"] = 1.5 * H                 # each step takes 1.5 steps of wall time
    clock.now += 5 * H
    start, steps_before = clock.now, node.sim.step_count
    node._next_publish = start          # a frame is due now
    node._tick()
    stepped = node.sim.step_count - steps_before
    elapsed = clock.now - start
    # It stepped until the tick's budget ran out, not a fixed few steps ...
    assert stepped == int(node_module.TICK_BUDGET // cost["s"]) + 1
    assert elapsed >= node_module.TICK_BUDGET > elapsed - cost["s"]
    # ... publishing between steps on the fixed schedule: one frame per
    # period of the elapsed time (within one), none ahead of the schedule,
    # never two without a step between them.
    assert abs(len(publishes) - elapsed * RATE) <= 1.0
    assert all(t >= start + k / RATE - 1e-9 for k, (t, _) in enumerate(publishes))
    counts = [count for _, count in publishes]
    assert counts == sorted(set(counts)) and counts[0] > steps_before


def test_faster_than_real_time_catches_up_exactly_and_waits(paced):
    node, clock, publishes, cost = paced
    cost["s"] = 0.5 * H
    clock.now += 5 * H
    node._tick()
    assert 0.0 <= _behind(node, clock) < H      # caught up to within one step
    count = node.sim.step_count
    node._tick()                                # no time has passed: nothing to do
    assert node.sim.step_count == count
    for _ in range(5):                          # a step period later: caught up again
        clock.now += H
        node._tick()
        assert 0.0 <= _behind(node, clock) < H
    assert node.sim.step_count > count


def test_unpaced_steps_once_per_tick(paced):
    node, clock, publishes, cost = paced
    node.set_parameters([Parameter("realtime", value=False)])
    node._apply_inputs()
    cost["s"] = 1.5 * H
    clock.now += 10 * H
    count = node.sim.step_count
    node._tick()
    assert node.sim.step_count == count + 1


def test_paused_does_not_step_but_still_publishes(paced):
    node, clock, publishes, cost = paced
    node.paused = True
    clock.now += 10 * H
    count = node.sim.step_count
    node._tick()
    assert node.sim.step_count == count
    assert len(publishes) == 1
