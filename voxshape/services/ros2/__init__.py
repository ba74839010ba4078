"""`voxshape ros2`: a real ROS 2 robot in a voxshape session, over rmw_zenoh (or a DDS robot's
zenoh-bridge-ros2dds). docs/robot.md says how to run it."""
