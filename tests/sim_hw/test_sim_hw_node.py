"""sim_hw_node in-process: lockstep exchange with a minimal controller, refusal of bad
commands, estop, command timeout, realtime mode and parameter validation."""

import math
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from pkm_common.conversions import joint_state_msg, pose_from_msg, stamp_to_ns
from pkm_common.params import ParameterError
from pkm_common.qos import LATCHED_QOS, STREAM_QOS
from pkm_sim_hw.hold_controller_node import HoldControllerNode
from pkm_sim_hw.sim_hw_node import SimHwNode

pytestmark = pytest.mark.ros


def overrides(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


class Recorder:
    def __init__(self, graph, msg_type, topic, qos=STREAM_QOS):
        self.messages = []
        self.node = graph.create_node(f"rec_{topic.replace('/', '_')}_{id(self)}")
        self.node.create_subscription(msg_type, topic, self.messages.append, qos)


def test_lockstep_with_a_hold_controller(ros_graph):
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="archi", publish_markers=False)))
    ctrl = ros_graph.add_node(HoldControllerNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="archi")))
    states = Recorder(ros_graph, JointState, "drives/state")
    poses = Recorder(ros_graph, PoseStamped, "platform/true_pose")
    assert ros_graph.spin_until(lambda: sim.plant.k >= 300, timeout_sec=30.0)
    # every step answered once, stamps consecutive multiples of dt
    stamps = sorted({stamp_to_ns(m.header.stamp) for m in states.messages})
    assert stamps[:300] == [k * 1_000_000 for k in range(300)]
    assert ctrl.answered >= 300
    # the pose published for step k matches the plant's tool pose (held near home)
    pose_stamps = {stamp_to_ns(m.header.stamp) for m in poses.messages}
    assert set(range(0, 300 * 1_000_000, 1_000_000)) <= pose_stamps
    position, _ = pose_from_msg(poses.messages[-1])
    np.testing.assert_allclose(position[:2], sim.config.model.home[:2], atol=1e-4)
    assert not sim.plant.stopped


def test_a_hexapod_in_lockstep_with_a_hold_controller(ros_graph):
    """genhexkins (kind struts): sim_hw runs the strut plant (parameters.PLANTS), publishes
    its six struts and the platform's full pose, takes a 6-component load, and the hold
    controller's static forces (rigid-body model) keep the platform at home."""
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="genhexkins", publish_markers=False)))
    ros_graph.add_node(HoldControllerNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="genhexkins")))
    states = Recorder(ros_graph, JointState, "drives/state")
    poses = Recorder(ros_graph, PoseStamped, "platform/true_pose")
    assert ros_graph.spin_until(lambda: sim.plant.k >= 200, timeout_sec=30.0)
    assert list(states.messages[-1].name) == ["j0", "j1", "j2", "j3", "j4", "j5"]
    position, rotation = pose_from_msg(poses.messages[-1])
    home = sim.config.model.home
    np.testing.assert_allclose(position, home[:3], atol=1e-5)
    np.testing.assert_allclose(rotation, np.eye(3), atol=1e-5)
    load = ros_graph.create_node("loader").create_publisher(WrenchStamped, "load", STREAM_QOS)
    assert ros_graph.spin_until(lambda: load.get_subscription_count() > 0)
    msg = WrenchStamped()
    msg.wrench.torque.z = 20.0
    load.publish(msg)
    assert ros_graph.spin_until(lambda: sim.plant.load[5] == 20.0, timeout_sec=5.0)
    k = sim.plant.k
    assert ros_graph.spin_until(lambda: sim.plant.k >= k + 200, timeout_sec=30.0)
    yaw = sim.plant.x[5]
    assert 1e-6 < yaw < 0.05 and not sim.plant.stopped       # turned by the moment, held by the PD


def test_bad_commands_are_refused_and_the_machine_stops(ros_graph):
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="archi", publish_markers=False)))
    diags = Recorder(ros_graph, DiagnosticArray, "diagnostics")
    pub_node = ros_graph.create_node("bad_commander")
    pub = pub_node.create_publisher(JointState, "drives/command", STREAM_QOS)
    ros_graph.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(joint_state_msg(sim.plant.names[:3], 0, effort=[1.0, 2.0, 3.0]))
    assert ros_graph.spin_until(lambda: sim.plant.stopped, timeout_sec=5.0)
    assert "refused command" in sim.plant.stop_reason and sim.counts["refused_commands"] == 1
    assert ros_graph.spin_until(lambda: any(s.level == DiagnosticStatus.ERROR for m in diags.messages for s in m.status))
    held = list(sim.plant.x)
    msg = joint_state_msg(sim.plant.names, sim.now_ns(), effort=[math.nan, 0.0, 0.0, 0.0])
    pub.publish(msg)
    assert ros_graph.spin_until(lambda: sim.counts["refused_commands"] == 2, timeout_sec=5.0)
    pub.publish(joint_state_msg(sim.plant.names, sim.now_ns(), effort=[2000.0] * 4))
    ros_graph.spin_for(0.2)
    assert sim.plant.x == held                    # brakes hold whatever comes


def test_timeout_and_estop(ros_graph):
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="mom3", publish_markers=False, command_timeout_s=0.3)))
    ctrl = ros_graph.add_node(HoldControllerNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="mom3")))
    assert ros_graph.spin_until(lambda: sim.plant.k >= 20, timeout_sec=20.0)
    ros_graph.executor.remove_node(ctrl)          # the controller dies
    started = time.monotonic()
    assert ros_graph.spin_until(lambda: sim.plant.stopped, timeout_sec=5.0)
    assert 0.25 < time.monotonic() - started < 1.5
    assert "no drives/command within 0.3 s" in sim.plant.stop_reason and sim.counts["timeouts"] == 1

    sim2 = ros_graph.add_node(SimHwNode(context=ros_graph.context, namespace="second", parameter_overrides=overrides(
        machine="mom3", publish_markers=False)))
    estop_node = ros_graph.create_node("estopper", namespace="second")
    estop = estop_node.create_publisher(Bool, "estop", LATCHED_QOS)
    estop.publish(Bool(data=True))
    assert ros_graph.spin_until(lambda: sim2.plant.stopped, timeout_sec=5.0)
    assert sim2.plant.stop_reason == "estop"


def test_realtime_mode_counts_deadline_misses(ros_graph):
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="mom3", publish_markers=False, mode="realtime", dt_s=0.01)))
    states = Recorder(ros_graph, JointState, "drives/state")
    ros_graph.spin_for(0.3)
    assert sim.plant.k == 0                       # held until the first command (no free fall)
    assert sim.counts["deadline_misses"] == 0
    pub = ros_graph.create_node("late").create_publisher(JointState, "drives/command", STREAM_QOS)
    ros_graph.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(joint_state_msg(sim.plant.names, 0, effort=[60.0] * 3))   # answers step 0, then silence
    # from then on it steps on its own (0.1 s of wall time; longer on a loaded machine)
    assert ros_graph.spin_until(lambda: sim.plant.k >= 10, timeout_sec=5.0)
    # the status word of each step says whether it applied the setpoint asked for; the
    # fifth held setpoint in a row, with no command at all, brakes: a silent controller
    status = {stamp_to_ns(m.header.stamp) // 10_000_000: m.header.frame_id for m in states.messages}
    assert status[1] == ""                        # step 0's command, answered in time
    assert [status[k] for k in range(2, 7)] == ["setpoint_held:0"] * 4 + ["safe_stop:watchdog"]   # step 0's again
    assert sim.plant.stop_reason.startswith("no drives/command for the last 5 cycles")
    # the misses of the running plant only: 4 held setpoints and the fifth, which
    # braked; the stopped plant's ticks go on holding step 0's setpoint uncounted
    assert ros_graph.spin_until(lambda: sim.plant.k >= 20, timeout_sec=5.0)
    assert sim.counts["deadline_misses"] == 5


def test_realtime_commands_that_keep_missing_the_cycle_brake_the_plant_named(ros_graph):
    """A controller one cycle late every time (it answers each state with the command
    for the one before): every step holds an older setpoint; the sync error counter
    brakes on the fifth, naming missed deadlines, not a drive or the following error."""
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="mom3", publish_markers=False, mode="realtime", dt_s=0.01)))
    node = ros_graph.create_node("late_controller")
    pub = node.create_publisher(JointState, "drives/command", STREAM_QOS)
    previous = []

    def answer_late(state):
        stamp = stamp_to_ns(state.header.stamp)
        pub.publish(joint_state_msg(sim.plant.names, previous[-1] if previous else stamp, effort=[58.9] * 3))
        previous.append(stamp)

    node.create_subscription(JointState, "drives/state", answer_late, STREAM_QOS)
    assert ros_graph.spin_until(lambda: sim.plant.stopped, timeout_sec=5.0)
    assert str(sim.plant.stop_cause) == "deadline_missed", sim.plant.stop_reason
    assert sim.plant.stop_reason.startswith("commands missed the plant's cycle: sync error count 15 > "
                                            "sync_error_limit 12")


@pytest.mark.parametrize("name,value,message", [
    ("machine", "hexapod", "unknown machine 'hexapod'"),
    ("dt_s", 0.5, r"'dt_s': must be a number in \[1e-05, 0.1\] s, got 0.5"),
    ("mode", "fast", "'mode': must be one of"),
    ("link_length_errors", [0.02, 0.0], "link_length_errors: must be 4 values"),
    ("faults", "9:locked", "faults: drive must be in"),
])
def test_invalid_parameters_fail_at_start_naming_the_field(ros_context, name, value, message):
    with pytest.raises((ParameterError, ValueError), match=message):
        SimHwNode(context=ros_context, parameter_overrides=overrides(**{name: value}))


def test_stale_commands_do_not_keep_the_machine_alive(ros_graph):
    """A controller stuck re-sending an old answer is not alive: timeout, brakes."""
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="mom3", publish_markers=False, command_timeout_s=0.3)))
    pub = ros_graph.create_node("stuck").create_publisher(JointState, "drives/command", STREAM_QOS)
    ros_graph.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(joint_state_msg(sim.plant.names, 0, effort=[58.9] * 3))         # step 0 answered
    assert ros_graph.spin_until(lambda: sim.plant.k == 1, timeout_sec=5.0)
    deadline = time.monotonic() + 1.5
    while time.monotonic() < deadline and not sim.plant.stopped:
        pub.publish(joint_state_msg(sim.plant.names, 0, effort=[58.9] * 3))     # stale, forever
        ros_graph.spin_for(0.02)
    assert sim.plant.stopped and sim.counts["timeouts"] == 1 and sim.counts["stale_commands"] > 5


@pytest.mark.parametrize("limit, reason", [
    (12, "no drives/command for the last 5 cycles"),     # the sync error counter: a few cycles
    (0, "no drives/command within 0.3 s"),                # without it, the command timeout
])
def test_realtime_stops_when_the_controller_dies(ros_graph, limit, reason):
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="mom3", publish_markers=False, mode="realtime", dt_s=0.01, command_timeout_s=0.3,
        sync_error_limit=limit)))
    pub = ros_graph.create_node("dying").create_publisher(JointState, "drives/command", STREAM_QOS)
    ros_graph.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(joint_state_msg(sim.plant.names, sim.now_ns(), effort=[58.9] * 3))
    assert ros_graph.spin_until(lambda: sim.plant.stopped, timeout_sec=3.0)
    assert str(sim.plant.stop_cause) == "watchdog" and sim.plant.stop_reason.startswith(reason)


# ---------------------------------------------------------------- command authority
def _hold_run(ros_graph, steps=50, **params):
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="archi", publish_markers=False, **params)))
    ctrl = ros_graph.add_node(HoldControllerNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="archi")))
    assert ros_graph.spin_until(lambda: sim.plant.k >= steps, timeout_sec=30.0)
    return sim, ctrl


def test_a_second_publisher_on_drives_command_is_an_intruder(ros_graph):
    """Only the controller the plant was connected to may move it: another node that
    merely publishes on drives/command (sending nothing) stops the machine, named."""
    sim, _ = _hold_run(ros_graph, command_source="/hold_controller")
    refused = Recorder(ros_graph, DiagnosticArray, "drives/refused")
    rogue = ros_graph.create_node("rogue")
    rogue.create_publisher(JointState, "drives/command", STREAM_QOS)
    assert ros_graph.spin_until(lambda: sim.plant.stopped, timeout_sec=5.0)
    assert str(sim.plant.stop_cause) == "intruder" and "/rogue" in sim.plant.stop_reason
    assert sim.run.intruder == "/rogue" and sim.summary()["intruder"] == "/rogue"
    assert ros_graph.spin_until(lambda: refused.messages, timeout_sec=5.0)
    values = {kv.key: kv.value for kv in refused.messages[0].status[0].values}
    assert values["cause"] == "intruder" and values["sender"] == "/rogue"


def test_an_intruders_forces_never_move_the_machine_in_real_time(ros_graph):
    """Realtime, the rogue sends 1e9 N commands stamped like the plant's step: the
    plant stops on its match (before its data), the tool stays where it was."""
    # sync_error_limit 0: the one-process test executor misses 1 ms cycles; not the point here
    sim, _ = _hold_run(ros_graph, mode="realtime", command_source="/hold_controller", sync_error_limit=0)
    rogue = ros_graph.create_node("rogue")
    pub = rogue.create_publisher(JointState, "drives/command", STREAM_QOS)
    x0 = list(sim.plant.x)
    for _ in range(200):
        pub.publish(joint_state_msg(sim.plant.names, sim.now_ns(), effort=[1e9] * 4))
        ros_graph.spin_for(0.002)
    assert sim.plant.stopped and str(sim.plant.stop_cause) == "intruder"
    assert max(abs(a - b) for a, b in zip(sim.plant.x[:2], x0[:2])) < 1e-5


def test_future_stamped_commands_are_refused(ros_graph):
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="archi", publish_markers=False, mode="realtime")))
    pub = ros_graph.create_node("ctrl").create_publisher(JointState, "drives/command", STREAM_QOS)
    ros_graph.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(joint_state_msg(sim.plant.names, sim.now_ns() + 10**9, effort=[500.0] * 4))
    assert ros_graph.spin_until(lambda: sim.plant.stopped, timeout_sec=5.0)
    assert str(sim.plant.stop_cause) == "input_refused" and "ahead of the plant" in sim.plant.stop_reason
    assert sim.counts["refused_commands"] == 1 and sim.plant.v == [0.0, 0.0, 0.0]


def test_the_drive_state_carries_the_plant_status_in_band(ros_graph):
    """frame_id '' while running, 'safe_stop:<cause>' once braked (a drive status word)."""
    sim, _ = _hold_run(ros_graph, steps=5)
    states = Recorder(ros_graph, JointState, "drives/state")
    ros_graph.spin_until(lambda: states.messages, timeout_sec=5.0)
    assert states.messages[-1].header.frame_id == ""
    estop = ros_graph.create_node("op").create_publisher(Bool, "estop", LATCHED_QOS)
    estop.publish(Bool(data=True))
    assert ros_graph.spin_until(lambda: states.messages and states.messages[-1].header.frame_id == "safe_stop:estop",
                                timeout_sec=5.0)


def test_a_load_over_its_bound_is_refused_and_stops(ros_graph):
    from geometry_msgs.msg import WrenchStamped
    sim, _ = _hold_run(ros_graph, steps=5, max_load_n=2000.0)
    pub = ros_graph.create_node("loader").create_publisher(WrenchStamped, "load", STREAM_QOS)
    ros_graph.spin_until(lambda: pub.get_subscription_count() > 0)
    msg = WrenchStamped()
    msg.wrench.force.x = 1e7
    pub.publish(msg)
    assert ros_graph.spin_until(lambda: sim.plant.stopped, timeout_sec=5.0)
    assert str(sim.plant.stop_cause) == "load_refused" and "max_load_n" in sim.plant.stop_reason
    assert sim.plant.load == [0.0, 0.0, 0.0] and sim.counts["refused_loads"] == 1


def test_refusals_are_logged_at_most_once_a_second(ros_graph):
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, parameter_overrides=overrides(
        machine="archi", publish_markers=False)))
    logged = []
    sim.get_logger().error = logged.append
    pub = ros_graph.create_node("bad").create_publisher(JointState, "drives/command", STREAM_QOS)
    ros_graph.spin_until(lambda: pub.get_subscription_count() > 0)
    for _ in range(30):
        pub.publish(joint_state_msg(sim.plant.names, sim.now_ns(), effort=[math.nan] * 4))
        ros_graph.spin_for(0.005)
    assert ros_graph.spin_until(lambda: sim.counts["refused_commands"] >= 20, timeout_sec=10.0)
    assert len(logged) == 1
