"""QoS profiles of the PKM graph, one per kind of topic (DESIGN.md "The graph").

Every publisher and subscriber of a topic uses the profile of this table, so that
endpoints always match (a RELIABLE subscriber never meets a BEST_EFFORT publisher,
a TRANSIENT_LOCAL subscriber gets the latched message).

| topic (relative to the namespace)              | type                          | profile       |
|------------------------------------------------|-------------------------------|---------------|
| `/clock`                                       | rosgraph_msgs/Clock           | CLOCK_QOS     |
| `drives/state`                                 | sensor_msgs/JointState        | STREAM_QOS    |
| `drives/command`                               | sensor_msgs/JointState        | STREAM_QOS    |
| `platform/true_pose`                           | geometry_msgs/PoseStamped     | STREAM_QOS    |
| `metrology/struts`                             | sensor_msgs/JointState        | STREAM_QOS    |
| `metrology/pose`                               | geometry_msgs/PoseStamped     | STREAM_QOS    |
| `controller/reference`, `controller/status`    | PoseStamped, DiagnosticArray  | STREAM_QOS    |
| `trajectory`                                   | trajectory_msgs/MultiDOFJointTrajectory | LATCHED_QOS |
| `markers`                                      | visualization_msgs/MarkerArray | LATCHED_QOS  |
| `goal`, `program`                              | PoseStamped, std_msgs/String  | STREAM_QOS    |
| `controller/feed_override`, `controller/settings` | std_msgs/String (a number, JSON) | STREAM_QOS |
| `run/start`                                    | std_msgs/String (`start`)     | LATCHED_QOS   |
| `controller/events`                            | std_msgs/String (JSON)        | EVENTS_QOS    |
| `load`                                         | geometry_msgs/WrenchStamped   | STREAM_QOS    |
| `estop`                                        | std_msgs/Bool                 | LATCHED_QOS   |
| `diagnostics`                                  | diagnostic_msgs/DiagnosticArray | STREAM_QOS  |

The commands (`goal`, `program`, `trajectory`, `load`, `controller/feed_override`,
`controller/settings`, `run/start`) carry the run's credential in their first string
(pkm_common.credential): `header.frame_id`, or a String's first line before its body.

- STREAM_QOS: RELIABLE, KEEP_LAST 10, VOLATILE. Lockstep exchanges one message per
  step and must not lose it (RELIABLE); depth 10 absorbs a burst while a callback
  runs without letting a slow reader fall behind by more than a few cycles.
- LATCHED_QOS: RELIABLE, KEEP_LAST 1, TRANSIENT_LOCAL: the last message is kept for
  late joiners (a controller started after the planner still gets the trajectory).
  `estop` is latched too: a node that starts during an emergency stop must see it.
- EVENTS_QOS: RELIABLE, KEEP_LAST 1000, TRANSIENT_LOCAL: the operator's actions as the
  controller applied them (pkm_controller.operator_actions); rare, and every one is needed to
  replay the run, so a recorder that subscribes late still gets them all.
- CLOCK_QOS: as rclpy's own `/clock` subscription (time_source.py): BEST_EFFORT,
  KEEP_LAST 1, VOLATILE. A publisher of `/clock` must offer at least this.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from pkm_common.topics import CATALOGUE

STREAM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=10,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)

LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)

EVENTS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1000,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)

CLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1,
    reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)

# Publishers of the per-step streams keep a deeper history than their subscribers ask
# for (depth matters on each side separately, it is not part of QoS matching): a
# RELIABLE KEEP_LAST writer drops a sample a slow reader has not acknowledged once its
# history is full, and a recorder starved of CPU for a few hundred steps on a loaded
# 2-core machine lost ~180 messages per topic with depth 10 (measured). 500 samples
# are 0.5 s at 1 kHz; a reader that keeps up never sees the difference.
STREAM_PUBLISHER_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=500,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)

# /clock offered RELIABLE (matches rclpy's BEST_EFFORT time source as well) so that a
# recorder can subscribe RELIABLE and lose no tick
CLOCK_PUBLISHER_QOS = STREAM_PUBLISHER_QOS

# The recording tap (pkm_recording.tap): a batch every 0.2 s, kept for a recorder that
# matches late (TRANSIENT_LOCAL, 50 batches = 10 s): nothing a node published before
# the recorder saw it is lost
TAP_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=50,
    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)

# topic (relative name) -> profile, for code that wires topics generically (the
# catalogue of pkm_common.topics: names, types, kinds)
PROFILES = {"stream": STREAM_QOS, "latched": LATCHED_QOS, "events": EVENTS_QOS, "clock": CLOCK_QOS}
TOPIC_QOS = {name: PROFILES[topic.qos] for name, topic in CATALOGUE.items()}



def publisher_qos(topic: str) -> QoSProfile:
    """What a publisher of ``topic`` (a relative name, or /clock) offers in the graph:
    the TOPIC_QOS profile, with the per-step streams' deeper publisher history."""
    qos = TOPIC_QOS.get(topic, STREAM_QOS)
    if qos is STREAM_QOS:
        return STREAM_PUBLISHER_QOS
    return CLOCK_PUBLISHER_QOS if qos is CLOCK_QOS else qos


__all__ = ['CLOCK_PUBLISHER_QOS', 'CLOCK_QOS', 'EVENTS_QOS', 'LATCHED_QOS', 'STREAM_PUBLISHER_QOS', 'STREAM_QOS', 'TAP_QOS',
           'TOPIC_QOS', 'publisher_qos']
