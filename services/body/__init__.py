"""The robot's body: its shapes, masses and frames from the robot description, below everything
that draws or simulates it (the simulator, the Foxglove scene, the ROS 2 bridge's URDF)."""
