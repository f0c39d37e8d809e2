"""Live view: the running simulation served to Foxglove over a WebSocket (no RViz needed).

Owns the Foxglove side of the project: :mod:`.server` (a ``foxglove-sdk``
WebSocket server publishing the cloth mesh coloured by level, the obstacles at
their current poses, the grasps, frame transforms and the LOD statistics),
:mod:`.scene` (those messages built from a simulator), :mod:`.protobuf` (the
bulk arrays of a mesh written straight into protobuf wire format) and
:mod:`.run` (a headless ``cloth-lod run`` served live at real-time speed).

May import the simulator (:mod:`cloth_lod_ros.sim`), the message builders'
ROS-free helpers (:mod:`cloth_lod_ros.messages.markers`) and ``foxglove``
(the optional ``viewer`` extra, imported only when a server starts); never
rclpy and never mcap, so ``cloth-lod run --foxglove`` works from a pip install
without the ROS wheels, and the node uses the same code.
"""
