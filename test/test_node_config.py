"""How cloth_lod_node starts: a bad ``scene`` parameter, the parameter file, the RViz view.

The node runs in its own process with the isolated ROS environment of
test_node.py (its own ROS_DOMAIN_ID, localhost-only discovery).
"""

import subprocess
import sys

import pytest

# Importing test_node first sets the isolated ROS environment.
from test_node import REPO, env

BAD_SCENE_TIMEOUT = 60.0         # s, generous: the node only has to start and refuse


def start_node(*ros_args, timeout=BAD_SCENE_TIMEOUT):
    return subprocess.run([sys.executable, "-m", "cloth_lod_ros.ros.node", "--ros-args",
                           *ros_args], env=env(), capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("case", ["missing", "syntax", "level", "directory", "aliases"])
def test_a_bad_scene_is_one_line_on_stderr_and_exit_code_2(tmp_path, case):
    scene, expected = {
        "missing": (tmp_path / "missing.yaml", "does not exist"),
        "syntax": (tmp_path / "syntax.yaml", "not valid YAML"),
        "level": (tmp_path / "level.yaml", "'cloth.level'"),
        "directory": (tmp_path, "is a directory"),
        "aliases": (tmp_path / "aliases.yaml", "alias"),
    }[case]
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
