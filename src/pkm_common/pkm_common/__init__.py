"""Shared helpers of the PKM nodes.

Thin-shell side (these import rclpy and messages):
  qos          QoS profiles, one per kind of topic (table in its docstring)
  conversions  stamps, PoseStamped, JointState, machine <-> tool pose, diagnostics
  params       typed, range-checked ROS parameters; ParameterError names the parameter
  runner       run_node(): init, spin, clean exit on SIGINT/SIGTERM, exit codes
  node_tap     a node's per-step streams handed to the recorder in batches

Pure (no rclpy):
  cdr          the per-step messages as CDR bytes
  causes       the trip vocabulary (TripCause) and the plant's status word
  sources      who may publish an input or a command (SourceGate, AllowedSenders, CommandGuard)
  credential   the run's key and the credential on every command (HMAC-SHA256)
  files        JSON written whole, summaries a full disk cannot crash
  domains      a private DDS domain per process (imported before rclpy)
  timing, watchdog, ratelimit, tap   durations, cadences, silence, rates, tap batches

Algorithms do not belong here: they live in the packages' pure-Python cores.
"""
