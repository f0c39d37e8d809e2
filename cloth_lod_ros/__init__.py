"""cloth_lod_ros: adaptive 4-8 cloth simulation for ROS 2 (layers: see docs/design.md §9)."""
