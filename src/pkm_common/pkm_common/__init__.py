"""Shared helpers of the PKM nodes.

Thin-shell side (these import rclpy and messages):
  qos          QoS profiles, one per kind of topic (table in its docstring)
  endpoints    a node's publishers and subscriptions, from the topic catalogue
  conversions  stamps, PoseStamped, JointState, machine <-> tool pose, diagnostics
  params       typed, range-checked ROS parameters (ParameterError: pkm_kinematics.errors)
  runner       run_node(): init, spin, clean exit on SIGINT/SIGTERM, exit codes

Pure (no rclpy):
  topics       the topic catalogue: name, message type, QoS kind
  cdr          the per-step messages as CDR bytes
  poses        pose fields of messages <-> task coordinates
  causes       the trip vocabulary (TripCause) and the plant's status (PlantStatus)
  sources      who may publish an input or a command (SourceGate, AllowedSenders, CommandGuard)
  credential   the run's key and the credential on every command (HMAC-SHA256)
  files        JSON written whole, summaries a full disk cannot crash
  domains      a private DDS domain per process (imported before rclpy)
  timing, watchdog, ratelimit   durations, cadences, silence, rates

Algorithms do not belong here: they live in the packages' pure-Python cores.
"""
