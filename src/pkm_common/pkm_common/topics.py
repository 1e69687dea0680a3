"""The graph's topics, one catalogue (DESIGN.md "The graph"): each topic's name
(relative to the machine namespace, or the absolute ``/clock``), its message type
and the kind of its QoS profile (pkm_common.qos turns a kind into a profile). Pure
(no rclpy): the recorder, the report and the replay read the same names the nodes
publish on.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["CATALOGUE", "QOS_KINDS", "Topic"]

QOS_KINDS = ("stream", "latched", "events", "clock")    # qos.STREAM_QOS, LATCHED_QOS, EVENTS_QOS, CLOCK_QOS


class Topic(NamedTuple):
    name: str            # relative to the namespace, or absolute (/clock)
    type: str            # package/msg/Type
    qos: str             # one of QOS_KINDS


CLOCK = "/clock"
DRIVES_STATE, DRIVES_COMMAND, DRIVES_REFUSED = "drives/state", "drives/command", "drives/refused"
TRUE_POSE = "platform/true_pose"
METROLOGY_STRUTS, METROLOGY_POSE = "metrology/struts", "metrology/pose"
CONTROLLER_REFERENCE, CONTROLLER_STATUS = "controller/reference", "controller/status"
CONTROLLER_EVENTS = "controller/events"
FEED_OVERRIDE, SETTINGS = "controller/feed_override", "controller/settings"
TRAJECTORY, GOAL, PROGRAM, RUN_START = "trajectory", "goal", "program", "run/start"
LOAD, ESTOP, MARKERS, DIAGNOSTICS = "load", "estop", "markers", "diagnostics"
DRIVES_CIA402 = "drives/cia402"       # each servo drive's CiA 402 state and error code (pkm_drives)
LASER_POINT = "instrument/laser"     # a laser tracker's reading of the tool point (calibration runs)
PROGRAM_EVENTS = "program/events"     # a trajectory's spindle, coolant and tool-change events (pkm_trajectory)

CATALOGUE: dict[str, Topic] = {t.name: t for t in (
    Topic(CLOCK, "rosgraph_msgs/msg/Clock", "clock"),
    Topic(DRIVES_STATE, "sensor_msgs/msg/JointState", "stream"),
    Topic(DRIVES_COMMAND, "sensor_msgs/msg/JointState", "stream"),
    Topic(DRIVES_REFUSED, "diagnostic_msgs/msg/DiagnosticArray", "stream"),
    Topic(DRIVES_CIA402, "diagnostic_msgs/msg/DiagnosticArray", "stream"),
    Topic(TRUE_POSE, "geometry_msgs/msg/PoseStamped", "stream"),
    Topic(METROLOGY_STRUTS, "sensor_msgs/msg/JointState", "stream"),
    Topic(METROLOGY_POSE, "geometry_msgs/msg/PoseStamped", "stream"),
    Topic(LASER_POINT, "geometry_msgs/msg/PoseStamped", "stream"),
    Topic(CONTROLLER_REFERENCE, "geometry_msgs/msg/PoseStamped", "stream"),
    Topic(CONTROLLER_STATUS, "diagnostic_msgs/msg/DiagnosticArray", "stream"),
    Topic(CONTROLLER_EVENTS, "std_msgs/msg/String", "events"),
    Topic(FEED_OVERRIDE, "std_msgs/msg/String", "stream"),
    Topic(SETTINGS, "std_msgs/msg/String", "stream"),
    Topic(TRAJECTORY, "trajectory_msgs/msg/MultiDOFJointTrajectory", "latched"),
    Topic(GOAL, "geometry_msgs/msg/PoseStamped", "stream"),
    Topic(PROGRAM, "std_msgs/msg/String", "stream"),
    Topic(RUN_START, "std_msgs/msg/String", "latched"),
    Topic(PROGRAM_EVENTS, "std_msgs/msg/String", "latched"),
    Topic(LOAD, "geometry_msgs/msg/WrenchStamped", "stream"),
    Topic(ESTOP, "std_msgs/msg/Bool", "latched"),
    Topic(MARKERS, "visualization_msgs/msg/MarkerArray", "latched"),
    Topic(DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray", "stream"),
)}
