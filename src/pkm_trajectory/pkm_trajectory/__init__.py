"""PKM trajectory planning: library and ROS 2 node."""
