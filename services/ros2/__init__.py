"""``invent ros2``: the robot as a ROS 2 citizen over rmw_zenoh (docs/ros2.md).

- :mod:`~services.ros2.wire`: rmw_zenoh's keys, liveliness tokens, QoS and attachments (pure);
- :mod:`~services.ros2.interfaces`: the ROS interfaces, their CDR and type hashes, from rosbags (pure);
- :mod:`~services.ros2.graph`: the bridge's topics, subscriptions and services, and their keys (pure);
- :mod:`~services.ros2.core`: ROS messages from the loop's, twists to targets, ``map``/``odom`` (pure);
- :mod:`~services.ros2.urdf`: the URDF, generated from the body the simulator builds (pure);
- :mod:`~services.ros2.service`: the bridge around them.
"""
