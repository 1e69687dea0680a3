"""Shared ROS helpers of the PKM nodes (thin-shell side: these import rclpy and messages).

  qos          QoS profiles, one per kind of topic (table in its docstring)
  conversions  stamps, PoseStamped, JointState, machine <-> tool pose, diagnostics
  params       typed, range-checked ROS parameters; ParameterError names the parameter
  runner       run_node(): init, spin, clean exit on SIGINT/SIGTERM, exit codes

Algorithms do not belong here: they live in the packages' pure-Python cores.
"""
