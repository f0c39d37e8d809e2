"""``cloth-lod play``: republish a recorded session with its original timing.

A ROS node (``cloth_lod_player``) with one publisher per recorded topic, of the
recorded type and with the recorded offered QoS (reliability, durability,
depth), so RViz or Foxglove sees what the recording node published.  Messages
go out as the recorded CDR bytes, spaced by their log times divided by
``rate``.  Like ``ros2 bag play`` it publishes every recorded topic by default,
including the recorded grasp poses: filter with ``topics`` when a live node
listens.
"""

from __future__ import annotations

import time

from ..bag.rosbag import BagError, BagReader
from ..bag.analysis import message_class

__all__ = ["play"]


def _qos(profiles: list):
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    p = profiles[0] if profiles else {}
    depth = int(p.get("depth") or 10)
    return QoSProfile(
        depth=max(depth, 1), history=HistoryPolicy.KEEP_LAST,
        reliability=(ReliabilityPolicy.BEST_EFFORT if p.get("reliability") == "best_effort"
                     else ReliabilityPolicy.RELIABLE),
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if p.get("durability") == "transient_local"
                    else DurabilityPolicy.VOLATILE))


def play(path, rate: float = 1.0, loop: bool = False, topics=None,
         delay: float = 0.0, on_publish=None) -> int:
    """Publish the bag's messages; returns 0 at the end (or on Ctrl-C / SIGTERM).

    Args:
        rate: speed factor (2 = twice as fast); must be positive.
        loop: start again after the last message.
        topics: only these topics (as recorded, e.g. ``/cloth/markers``).
        delay: s to wait after creating the publishers (discovery) before the first message.
        on_publish: called with each published :class:`~cloth_lod_ros.bag.rosbag.BagMessage`.

    Raises:
        BagError: unreadable bag, unknown topic or message type, bad rate.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    if not rate > 0:
        raise BagError(f"--rate must be positive, got {rate}")
    with BagReader(path) as reader:
        chosen = list(reader.topics) if not topics else list(topics)
        unknown = sorted(set(chosen) - set(reader.topics))
        if unknown:
            raise BagError(f"{path}: no topic(s) {unknown}; recorded: {sorted(reader.topics)}")
        infos = {t: reader.topics[t] for t in chosen}
        classes = {t: message_class(i.type_name) for t, i in infos.items()}
        messages = list(reader.messages(chosen))
    if not messages:
        raise BagError(f"{path}: no messages on {chosen}")
    rclpy.init()
    node = None
    try:
        node = rclpy.create_node("cloth_lod_player")
        publishers = {t: node.create_publisher(classes[t], t, _qos(i.qos))
                      for t, i in infos.items()}
        node.get_logger().info(f"playing {len(messages)} messages on {len(publishers)} topics "
                               f"from {path} at rate {rate:g}")
        time.sleep(max(delay, 0.0))
        while True:
            wall_start = time.monotonic()
            first = messages[0].time_ns
            for m in messages:
                delay = wall_start + (m.time_ns - first) * 1e-9 / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if not rclpy.ok():
                    return 0
                publishers[m.topic].publish(m.data)
                if on_publish is not None:
                    on_publish(m)
            if not loop:
                break
        # Let late-joining subscribers of latched topics and the last reliable
        # messages get out before the publishers are destroyed.
        time.sleep(0.5)
        return 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
