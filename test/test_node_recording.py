"""The node's recording state (ros/recording.py), without a node: names that never
collide, a failure that clears, and the same answer for the same state (issue 34)."""

from __future__ import annotations

import time
import types

import pytest

import rclpy  # noqa: E402,F401  (the test extra installs it: without it these fail, never skip)

from cloth_lod_ros.bag.rosbag import BagError  # noqa: E402
from cloth_lod_ros.ros import recording as recmod  # noqa: E402
from cloth_lod_ros.ros.recording import NodeRecording  # noqa: E402
from cloth_lod_ros.sim.scene.config import load_scene  # noqa: E402


class Logger:
    def __init__(self):
        self.lines = []

    def __getattr__(self, level):
        return lambda text, **kw: self.lines.append((level, text))


@pytest.fixture
def rec(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)             # dated names are relative: bags/...
    return NodeRecording("/", "none", [], Logger(), lambda: True)


SIM = types.SimpleNamespace(scene=load_scene("hang_two_corners"), step_count=0, time=0.0)


def start(rec, path=""):
    return rec.start(path, SIM, {}, 21, time.time_ns())


def fail_while_writing(rec):
    """The disk fails under the bag being written (as a full disk does)."""
    def write(*args, **kwargs):
        raise BagError("No space left on device")
    rec.recorder.writer.write = write
    rec.recorder.record_input(SIM, "pause")
    for _ in range(200):
        if rec.recorder.failed:
            return
        time.sleep(0.01)
    raise AssertionError("the writer thread never saw the failure")


def test_dated_names_started_within_one_second_never_collide(rec, tmp_path):
    paths = []
    for _ in range(5):                       # false, true, true... within one second
        started, text = start(rec)
        assert started, text
        paths.append(rec.recorder.path)
        assert rec.stop()[0]
    assert len(set(paths)) == 5
    assert all(p.exists() and (p / "metadata.yaml").exists() for p in paths)


def test_a_named_path_that_exists_gets_a_counter_never_overwritten(rec, tmp_path):
    assert start(rec, "mine")[0] and rec.stop()[0]
    started, text = start(rec, "mine")
    assert started and text == "recording to mine_2"
    assert rec.stop()[0]
    (tmp_path / "mine_3").write_text("a file, not a bag")
    assert start(rec, "mine") == (True, "recording to mine_4")


def test_record_false_answers_the_same_way_for_the_same_state(rec):
    assert rec.stop() == (True, "not recording")
    assert rec.stop() == (True, "not recording")
    assert rec.status() == "off"


def test_a_failure_shows_until_a_new_bag_starts_or_it_is_cleared(rec):
    assert start(rec)[0]
    fail_while_writing(rec)
    assert rec.status() == "failed: No space left on device"
    ok, text = rec.stop()                    # finishing the failed bag: it failed
    assert not ok and text.startswith("recording failed: No space left on device")
    assert rec.status().startswith("failed: ")
    # Asked: record false while not recording clears it, then answers as for "off".
    assert rec.stop() == (True, "not recording; cleared the failure: No space left on device")
    assert rec.status() == "off" and rec.stop() == (True, "not recording")
    # A new bag clears it too.
    assert start(rec)[0]
    fail_while_writing(rec)
    assert rec.stop()[0] is False
    assert start(rec)[0] and rec.status().startswith("on: ")


def test_a_bag_that_cannot_be_created_is_reported_and_cleared_by_the_next(rec, tmp_path):
    (tmp_path / "a_file").write_text("")
    started, text = start(rec, "a_file/bag")
    assert not started and text.startswith("recording not started: cannot create the bag")
    assert rec.status().startswith("failed: cannot create the bag")
    assert start(rec, "elsewhere") == (True, "recording to elsewhere")
    assert rec.status() == "on: elsewhere"


def test_dated_names_have_milliseconds(rec):
    name = recmod._dated_name()
    assert name.startswith("bags/cloth_lod_") and len(name.rsplit("_", 1)[1]) == 3
