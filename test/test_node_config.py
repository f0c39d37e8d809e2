"""How cloth_lod_node starts: a bad ``scene`` parameter, the parameter file, the RViz view.

The node runs in its own process with the isolated ROS environment of
test_node.py (its own ROS_DOMAIN_ID, localhost-only discovery).
"""

import re
import signal
import subprocess
import sys
import time

import pytest
import yaml

# Importing test_node first sets the isolated ROS environment.
from test_node import REPO, env, observer, scene_file  # noqa: F401

import rclpy  # noqa: E402
from rcl_interfaces.srv import GetParameters  # noqa: E402

BAD_SCENE_TIMEOUT = 60.0         # s, generous: the node only has to start and refuse


def start_node(*ros_args, timeout=BAD_SCENE_TIMEOUT):
    return subprocess.run([sys.executable, "-m", "cloth_lod_ros.ros.node", "--ros-args",
                           *ros_args], env=env(), capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("case", ["missing", "syntax", "level", "directory", "aliases",
                                  "budget"])
def test_a_bad_scene_is_one_line_on_stderr_and_exit_code_2(tmp_path, case):
    scene, expected = {
        "missing": (tmp_path / "missing.yaml", "does not exist"),
        "syntax": (tmp_path / "syntax.yaml", "not valid YAML"),
        "level": (tmp_path / "level.yaml", "'cloth.level'"),
        "directory": (tmp_path, "is a directory"),
        "aliases": (tmp_path / "aliases.yaml", "alias"),
        "budget": (tmp_path / "budget.yaml", "the limit is 32,768 triangles at the start"),
    }[case]
    (tmp_path / "budget.yaml").write_text(      # within every field's range, over the budget
        "cloth: {width: 1, height: 1, base_blocks: [4, 4], level: 12}\n"
        "simulation: {time_step: 0.02, duration: 1}\n")
    (tmp_path / "syntax.yaml").write_text("cloth: {width: 1.0, height: [1.0\n")
    (tmp_path / "level.yaml").write_text(
        "cloth: {width: 1, height: 1, base_blocks: [4, 4], level: 30}\n"
        "simulation: {time_step: 0.02, duration: 1}\n")
    (tmp_path / "aliases.yaml").write_text(
        "cloth: &c {width: 1, height: 1, base_blocks: [4, 4]}\n"
        "simulation: {time_step: 0.02, duration: 1}\nlod: *c\n")
    proc = start_node("-p", f"scene:={scene}")
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("cloth_lod_node: scene error: "), lines[0]
    assert expected in lines[0], lines[0]
    assert "Traceback" not in proc.stdout + proc.stderr
    if case == "directory":
        assert "does not exist" not in lines[0]


# -- the parameter file and the RViz view under a namespace ----------------------------------

def test_parameter_file_applies_to_the_node_in_any_namespace():
    data = yaml.safe_load((REPO / "config" / "cloth_lod.yaml").read_text())
    assert list(data) == ["/**"], "keyed by node name, a namespaced node ignores it"
    assert data["/**"]["ros__parameters"]["scene"] == "hang_two_corners"


def test_a_namespaced_node_gets_the_parameter_file_values(observer, scene_file, tmp_path):
    """``-r __ns:=/robot1 --params-file config/cloth_lod.yaml`` used to run with the
    declared defaults: the file was keyed by the node's name, which only matches at /."""
    text = (REPO / "config" / "cloth_lod.yaml").read_text()
    changed = re.sub(r"(?m)^(\s+)publish_rate:.*$", r"\g<1>publish_rate: 7.5", text)
    changed = re.sub(r"(?m)^(\s+)grid_resolution:.*$", r"\g<1>grid_resolution: 9", changed)
    changed = re.sub(r"(?m)^(\s+)scene:.*$", rf"\g<1>scene: {scene_file}", changed)
    assert changed.count("7.5") == 1 and "grid_resolution: 9" in changed
    params = tmp_path / "cloth_lod.yaml"
    params.write_text(changed)
    proc = subprocess.Popen([sys.executable, "-m", "cloth_lod_ros.ros.node", "--ros-args",
                             "-r", "__ns:=/robot1", "--params-file", str(params)],
                            env=env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        client = observer.create_client(GetParameters, "/robot1/cloth_lod_node/get_parameters")
        assert client.wait_for_service(timeout_sec=30.0), proc.poll()
        future = client.call_async(GetParameters.Request(
            names=["publish_rate", "grid_resolution", "scene"]))
        end = time.monotonic() + 30.0
        while not future.done() and time.monotonic() < end:
            rclpy.spin_once(observer, timeout_sec=0.05)
        values = future.result().values
        observer.destroy_client(client)
        assert values[0].double_value == 7.5
        assert values[1].integer_value == 9
        assert values[2].string_value == str(scene_file)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            assert proc.wait(timeout=10) == 0, proc.stdout.read()
        except subprocess.TimeoutExpired:
            proc.kill()
            raise


def test_rviz_view_uses_relative_topics():
    """Absolute topics (/cloth/markers) miss a node run in a namespace; relative ones
    resolve in RViz's namespace, as the node's own names do."""
    view = yaml.safe_load((REPO / "config" / "cloth_lod.rviz").read_text())
    topics, stack = [], [view]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            for key, value in item.items():
                if key == "Topic":
                    topics.append(value["Value"] if isinstance(value, dict) else value)
                else:
                    stack.append(value)
        elif isinstance(item, list):
            stack.extend(item)
    assert sorted(topics) == ["cloth/grid", "cloth/markers"]
    assert not [t for t in topics if t.startswith("/")]
