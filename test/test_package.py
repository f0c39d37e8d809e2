"""package.xml: every dependency is a rosdep key that rosdistro knows.

``rosdep install --from-paths src`` exits 1 on any key it cannot resolve (the
``python3-*-pip`` keys it once listed do not exist), so the keys are checked
against an explicit list of keys known to rosdistro: the ROS 2 Jazzy packages
this package uses and the system keys of ``rosdep/python.yaml``.  Python
packages that only pip provides (mcap, rosbags, mcap-ros2-support) are not
dependencies here (see the comment in package.xml and the README).
"""

import ast
import xml.etree.ElementTree as ElementTree
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

ROS_PACKAGES = {
    "rclpy", "rcl_interfaces", "rosgraph_msgs", "visualization_msgs", "geometry_msgs",
    "std_msgs", "std_srvs", "diagnostic_msgs", "sensor_msgs",
    "launch", "launch_ros", "ament_index_python", "rviz2",
}
SYSTEM_KEYS = {"python3-numpy", "python3-scipy", "python3-yaml", "python3-matplotlib",
               "python3-pytest", "python3-hypothesis"}
DEPEND_TAGS = ("depend", "build_depend", "build_export_depend", "buildtool_depend",
               "exec_depend", "run_depend", "test_depend", "doc_depend")


def dependencies() -> dict[str, set[str]]:
    root = ElementTree.parse(REPO / "package.xml").getroot()
    return {tag: {e.text.strip() for e in root.iter(tag)} for tag in DEPEND_TAGS}


def test_every_dependency_is_a_known_rosdep_key():
    keys = set().union(*dependencies().values())
    assert keys, "no dependencies parsed"
    unknown = keys - ROS_PACKAGES - SYSTEM_KEYS
    assert not unknown, f"not rosdep keys of rosdistro: {sorted(unknown)}"
    assert not [k for k in keys if k.endswith("-pip")]


def test_launch_file_rviz_and_clock_needs_are_declared():
    run = dependencies()["exec_depend"] | dependencies()["depend"]
    assert {"launch", "launch_ros", "ament_index_python", "rviz2", "rosgraph_msgs"} <= run
    assert {"python3-numpy", "python3-scipy", "python3-yaml", "python3-matplotlib"} <= run
    assert {"python3-pytest", "python3-hypothesis"} <= dependencies()["test_depend"]


def _imported_top_level_modules(paths) -> set[str]:
    names = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names


def test_every_ros_package_the_code_imports_is_declared():
    sources = list((REPO / "cloth_lod_ros").rglob("*.py")) + list((REPO / "config").glob("*.py"))
    imported = _imported_top_level_modules(sources)
    ros = {name for name in imported if name in ROS_PACKAGES
           or name.endswith(("_msgs", "_srvs", "_interfaces"))}
    assert {"rclpy", "launch_ros"} <= ros                    # the scan sees the imports
    run = dependencies()["exec_depend"] | dependencies()["depend"]
    assert not ros - run, f"imported but not in package.xml: {sorted(ros - run)}"
