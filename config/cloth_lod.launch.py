"""Launch cloth_lod_node with config/cloth_lod.yaml (for a normal ROS 2 install;
launch is not available from PyPI, so this file is not exercised by the tests).

    ros2 launch cloth_lod_ros cloth_lod.launch.py scene:=grasp_lift rviz:=true
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    share = get_package_share_directory("cloth_lod_ros")
    return LaunchDescription([
        DeclareLaunchArgument("scene", default_value="hang_two_corners"),
        DeclareLaunchArgument("rviz", default_value="false"),
        Node(package="cloth_lod_ros", executable="cloth_lod_node", name="cloth_lod_node",
             output="screen",
             parameters=[os.path.join(share, "config", "cloth_lod.yaml"),
                         {"scene": LaunchConfiguration("scene")}]),
        Node(package="rviz2", executable="rviz2", output="screen",
             arguments=["-d", os.path.join(share, "config", "cloth_lod.rviz")],
             condition=IfCondition(LaunchConfiguration("rviz"))),
    ])
