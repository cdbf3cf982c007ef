"""The gateway on a robot's ROS 2 graph over DDS, without a ROS installation (``--ros2``).

* :mod:`pfdoa.ros2.typedesc` - message types from their ``.msg`` definitions, ROS 2's DDS
  names and the REP-2011 type hashes (no dependency);
* :mod:`pfdoa.ros2.config` - the site file's ``[ros2]`` table (no dependency);
* :mod:`pfdoa.ros2.dds` - the DDS participant, types and QoS through Eclipse Cyclone DDS
  (PyPI ``cyclonedds``, the optional extra ``ros2``).

The sink that publishes is :mod:`pfdoa.sinks.ros2`, the odometry it subscribes to comes in
through :mod:`pfdoa.sinks.ros2odom`; docs/robot.md says how a robot uses them.
"""
