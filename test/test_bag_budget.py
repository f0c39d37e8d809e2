"""The recording's budget (bag/recorder.py; issue 34): received messages take at most a
stated rate of the bag, rejected inputs are recorded bounded, the writer queue is
bounded and says when it drops.  In-process, with an injected clock; the node-level
flood from a separate process is in test_bag.py."""

from __future__ import annotations

import json
import threading
import types

import pytest

import rclpy  # noqa: E402,F401  (the test extra installs it: without it these fail, never skip)

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from cloth_lod_ros.bag import recorder as recmod  # noqa: E402
from cloth_lod_ros.bag.recorder import (INPUT_BURST_BYTES, INPUT_BYTES_PER_S,  # noqa: E402
                                        REJECTED_TEXT_CHARS, ByteBudget, SessionRecorder)
from cloth_lod_ros.bag.rosbag import BagReader  # noqa: E402
from cloth_lod_ros.sim.scene.config import load_scene  # noqa: E402

SIM = types.SimpleNamespace(scene=load_scene("hang_two_corners"), step_count=0, time=0.0)
INPUT_TOPICS = ("/cloth/rejected", "/grasp/hand/pose")


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_a_token_bucket_never_gives_more_than_rate_times_time_plus_burst():
    clock = Clock()
    budget = ByteBudget(1000, 4000, clock)
    taken = 0
    for k in range(20_000):                 # 20 s of 1 kHz requests of 0..700 bytes
        clock.now = k * 1e-3
        size = (k * 37) % 701
        taken += size if budget.take(size) else 0
        assert taken <= 4000 + 1000 * clock.now
    assert taken >= 1000 * 20 * 0.95        # and it does give the rate when asked for more


def flood(rec, clock, seconds=20.0, rate=500, frame_chars=100_000):
    """``rate`` poses/s for ``seconds``: every other one rejected (a 100 kB frame id),
    the others accepted (recorded as received)."""
    sent = int(seconds * rate)
    big = "x" * frame_chars
    pose = PoseStamped()
    pose.header.frame_id = "world"
    accepted = serialize_message(pose)
    for k in range(sent):
        clock.now = k / rate
        if k % 2:
            rec.record_message("grasp/hand/pose", accepted)
        else:
            rec.record_rejected("grasp/hand/pose", "frame", frame_id=big, stamp=[k, 0],
                                position=[float("nan"), 0.0, 1e300],
                                orientation=[0.0, 0.0, 0.0, 1.0])
    return sent


def input_bytes(path) -> tuple[int, list]:
    with BagReader(path) as reader:
        messages = list(reader.messages(INPUT_TOPICS))
    return sum(len(m.data) for m in messages), messages


def test_a_flood_of_500_poses_per_second_with_100_kb_frame_ids_is_bounded(tmp_path):
    """The issue's target: a 20 s flood grows the bag by at most 1 MB; the budget
    makes it at most 20 kB/s x 20 s + the burst."""
    clock = Clock()
    rec = SessionRecorder(tmp_path / "bag", "/", "none", grasp_names=["hand"])
    rec.input_budget = ByteBudget(INPUT_BYTES_PER_S, INPUT_BURST_BYTES, clock)
    rec.start(SIM)
    sent = flood(rec, clock)
    rec.close()
    total, messages = input_bytes(tmp_path / "bag")
    assert total <= INPUT_BURST_BYTES + INPUT_BYTES_PER_S * 20.0 <= 1_000_000
    assert total >= 0.9 * INPUT_BYTES_PER_S * 20.0       # the budget is used, not starved
    rejected = [json.loads(deserialize_message(m.data, String).data)
                for m in messages if m.topic == "/cloth/rejected"]
    recorded_poses = sum(m.topic == "/grasp/hand/pose" for m in messages)
    assert rejected and recorded_poses
    # Every input is either recorded or counted, and the records say how many not.
    assert len(rejected) + recorded_poses + rec.unrecorded == sent
    assert sum(r["unrecorded_before"] for r in rejected) <= rec.unrecorded
    for r in rejected:                                   # bounded, JSON-safe copies
        assert r["reason"] == "frame" and r["topic"] == "/grasp/hand/pose"
        assert r["frame_id"].startswith("x" * REJECTED_TEXT_CHARS)
        assert r["frame_id"].endswith("(100000 chars)")
        assert r["position"] == ["nan", 0.0, 1e300]
    assert max(len(m.data) for m in messages) < 1000


def test_the_writer_queue_is_bounded_and_counts_what_it_drops(tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(recmod, "MAX_QUEUED_BYTES", 50_000)
    rec = SessionRecorder(tmp_path / "bag", "/", "none")
    release = threading.Event()
    write = rec.writer.write

    def stalled(*args):                      # a disk that does not answer
        release.wait(30)
        return write(*args)
    rec.writer.write = stalled
    rec.start(SIM)                           # the session message is never dropped
    payload = serialize_message(String(data="y" * 1000))
    for k in range(200):                     # 200 kB of inputs against a 50 kB queue
        rec._write("cloth/inputs", payload, k)
    assert 140 <= rec.dropped_messages <= 160
    assert "messages dropped" in caplog.text
    release.set()
    rec.close()
    with BagReader(tmp_path / "bag") as reader:
        assert reader.topics["/cloth/session"].message_count == 1
        assert reader.topics["/cloth/inputs"].message_count == 200 - rec.dropped_messages
