"""ament_python package: installable with colcon (ROS install) or pip (PyPI wheels)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "cloth_lod_ros"

# ROS 2 Jazzy from PyPI wheels (only for a virtual environment without a ROS
# install; colcon users get these from their distribution).  Pinned: the bare
# ros-* names on PyPI are a newer distribution.
ROS_WHEELS = [
    "ros-jazzy-rclpy[fastrtps]==7.1.6",
    "ros-jazzy-common-interfaces==5.3.6",
]
# Recording sessions (rosbag2 MCAP bags); mcap brings zstd and lz4.
BAG = ["mcap>=1.2"]
# Independent readers used by the tests to check our bags.
BAG_READERS = ["mcap-ros2-support>=0.5", "rosbags>=0.10"]
# The live view (cloth_lod_ros/live): Foxglove's WebSocket server (MIT; abi3
# wheels for x86_64 and aarch64, manylinux_2_28; no dependencies).
VIEWER = ["foxglove-sdk>=0.30"]
# `cloth-lod view` writes MP4 (H.264) through the ffmpeg binary that imageio-ffmpeg
# (BSD-2) ships in its wheel and runs as a separate program (a GPL-3 build with
# libx264); without it, `view` writes GIF.
VIEWER += ["imageio-ffmpeg>=0.5"]
# A Foxglove WebSocket client and protobuf decoder, written independently of the
# SDK, with which the tests check what the live view sends.
VIEWER_CLIENT = ["websockets>=13", "protobuf>=4.25"]
# `cloth-lod sweep` (and `cloth-lod bench --scheduler`): runs as tasks on
# dask.distributed (BSD-3, pure Python), a LocalCluster or an existing scheduler.
CLUSTER = ["dask[distributed]>=2024.1"]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.rviz")),
        (f"share/{PACKAGE}/config/scenes", glob("config/scenes/*.yaml")),
        (f"share/{PACKAGE}/config/bench", glob("config/bench/*.yaml")),
        (f"share/{PACKAGE}/config/sweeps", glob("config/sweeps/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("config/*.launch.py")),
    ],
    python_requires=">=3.10",
    # qdldl: the sparse LDL^T behind solver.method direct and the ordering of
    # block_ldl; numba: the compiled force/assembly kernels and block_ldl
    # (forces + assembly 3-5x, factorisation 2.5-3x faster; wheels for x86_64
    # and aarch64, glibc >= 2.28).  Without either the simulator falls back to
    # its numpy reference code and PCG/multigrid.  threadpoolctl (pure Python):
    # one BLAS thread inside a step (sim/runtime/blas_threads.py: idle threads spun
    # on the second core, and the thread count changed results at round-off).
    # Lower bounds only (a library; the tested versions are pinned in
    # constraints.txt, scripts/refresh-constraints), except where a major
    # release is known to break: numpy's majors remove API (2.0 did, and numba
    # releases cap the numpy they support), and scipy's docs announce that the
    # sparse *matrix* classes we build (bsr_matrix, csr_matrix) will give way
    # to the sparse arrays, a change for its next major.
    install_requires=["setuptools", "numpy>=1.24,<3", "scipy>=1.10,<2", "PyYAML>=6",
                      "matplotlib>=3.6", "qdldl>=0.1.7", "numba>=0.60",
                      "threadpoolctl>=3.1"],
    extras_require={
        "ros": ROS_WHEELS + BAG,
        "test": ROS_WHEELS + BAG + BAG_READERS + VIEWER + VIEWER_CLIENT + CLUSTER
                + ["pytest>=7", "hypothesis>=6"],
        # mcap: `cloth-lod view` reads bags.
        "viewer": VIEWER + BAG,
        "cluster": CLUSTER,
        # Optional: CHOLMOD's supernodal Cholesky for solver.method cholmod/auto
        # (about 0.4x QDLDL's factorisation).  cvxopt is GPL-3.0: not installed
        # by default.
        "cholmod": ["cvxopt>=1.3"],
    },
    zip_safe=True,
    maintainer="cloth_lod_ros maintainers",
    maintainer_email="maintainers@cloth-lod-ros.invalid",
    description="Adaptive 4-8 level-of-detail cloth simulation for ROS 2",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "cloth-lod = cloth_lod_ros.tools.cli:main",
            "cloth_lod_node = cloth_lod_ros.ros.startup:node_main",   # prints before the imports
        ],
    },
)
