"""controller_node in-process: lifecycle and parameter refusal, the ARCHI test motion
through trajectory_node -> controller -> sim_hw in lockstep, MoM3 sensor space with
the Gough node in the loop under load, bad state messages, the watchdog."""

import time
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from pkm_common.causes import TripCause
from pkm_common.qos import LATCHED_QOS, STREAM_QOS
from pkm_controller.controller_node import ControllerNode
from pkm_gough_sensor.gough_sensor_node import GoughSensorNode
from pkm_kinematics import load_machine
from pkm_sim_hw.sim_hw_node import SimHwNode
from pkm_trajectory.trajectory_node import TrajectoryNode

ROOT = Path(__file__).resolve().parents[2]
ARCHI = load_machine("archi")


def overrides(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


@pytest.mark.ros
def test_a_bad_parameter_refuses_configure_naming_it(ros_context):
    with pytest.raises(ValueError, match=r"parameter 'strategy': must be one of \['joint_pid'"):
        ControllerNode(context=ros_context, parameter_overrides=overrides(strategy="magic"))
    node = ControllerNode(context=ros_context, parameter_overrides=overrides(
        autostart=False, bandwidth_hz=900.0))
    try:
        assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
        assert node.configure_error.startswith("parameter 'bandwidth_hz': must be in (0, 100] Hz")
    finally:
        node.destroy_node()


@pytest.mark.ros
def test_lifecycle_configure_activate_deactivate(ros_graph):
    ctrl = ros_graph.add_node(ControllerNode(context=ros_graph.context, parameter_overrides=overrides(
        autostart=False)))
    estops = []
    probe = ros_graph.create_node("probe")
    probe.create_subscription(Bool, "estop", lambda m: estops.append(m.data), LATCHED_QOS)
    assert ctrl.trigger_configure() == TransitionCallbackReturn.SUCCESS
    assert ctrl.trigger_activate() == TransitionCallbackReturn.SUCCESS and ctrl.loop.active
    assert ctrl.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
    assert ros_graph.spin_until(lambda: estops == [True], timeout_sec=5.0)   # brakes requested
    assert ctrl.core.stop_reason == "deactivated"
    assert ctrl.trigger_cleanup() == TransitionCallbackReturn.SUCCESS and ctrl.core is None


@pytest.mark.ros
def test_archi_test_motion_through_the_graph(ros_graph):
    """trajectory_node plans the ARCHI test motion (G-code), the controller
    (computed torque, inf-norm) executes it in lockstep with sim_hw: every state
    answered, the tool back at home within 2 um, peak tracking error under 50 um."""
    ctx = ros_graph.context
    sim = ros_graph.add_node(SimHwNode(context=ctx, parameter_overrides=overrides(publish_markers=False)))
    ros_graph.add_node(TrajectoryNode(context=ctx, parameter_overrides=overrides(
        program_file=str(ROOT / "config" / "programs" / "archi_test_motion.nc"))))
    ctrl = ros_graph.add_node(ControllerNode(context=ctx, parameter_overrides=overrides(
        distribution="inf_norm")))
    status = []
    probe = ros_graph.create_node("probe")
    probe.create_subscription(DiagnosticArray, "controller/status", lambda m: status.append(m.status[0]), STREAM_QOS)
    assert ros_graph.spin_until(lambda: sim.plant.k >= 5000, timeout_sec=120.0)
    core = ctrl.core
    assert not core.stopped, core.stop_reason
    assert core.reference is not None and core.reference.duration_s == pytest.approx(4.656, abs=1e-3)
    assert core.mode == "holding" and core.cycles >= 4999
    np.testing.assert_allclose(sim.plant.output().tool_pose, ARCHI.model.home, atol=2e-6)
    assert 1e-6 < core.max_error_m < 5e-5
    assert status and status[-1].level == b"\x00"
    values = {kv.key: kv.value for kv in status[-1].values}
    assert values["distribution"] == "inf_norm" and float(values["peak_drive_force_n"]) > 50.0


@pytest.mark.ros
def test_a_long_callback_of_another_node_trips_neither_end_of_the_loop(ros_graph):
    """All nodes in one executor: another node's callback holds it for 1.5 s, longer
    than sim_hw's 1 s command timeout and the controller's 0.5 s state timeout. The
    commands and states wait in the queues meanwhile; neither end calls it silence
    (pkm_common.watchdog), and the loop goes on."""
    ctx = ros_graph.context
    sim = ros_graph.add_node(SimHwNode(context=ctx, parameter_overrides=overrides(publish_markers=False)))
    ctrl = ros_graph.add_node(ControllerNode(context=ctx))
    stalled_at = []

    def hold_the_executor():
        if sim.plant.k >= 200 and not stalled_at:
            stalled_at.append(sim.plant.k)
            time.sleep(1.5)
    ros_graph.create_node("busy").create_timer(0.01, hold_the_executor)
    assert ros_graph.spin_until(lambda: stalled_at and sim.plant.k >= stalled_at[0] + 300, timeout_sec=60.0)
    assert not sim.plant.stopped, sim.plant.stop_reason
    assert not ctrl.core.stopped, ctrl.core.stop_reason
    assert sim.counts["timeouts"] == 0


@pytest.mark.ros
def test_sensor_space_with_the_gough_node_in_the_loop(ros_graph):
    """MoM3: 110 N on the tool, compliance 0.7 um/N: the structure deflects 77 um, the
    controller closes the loop on the Gough struts and the tool stays within 1.5 um."""
    ctx = ros_graph.context
    sim = ros_graph.add_node(SimHwNode(context=ctx, parameter_overrides=overrides(
        machine="mom3", publish_markers=False, compliance=[0.7e-6, 0.7e-6, 0.7e-6])))
    ros_graph.add_node(GoughSensorNode(context=ctx, parameter_overrides=overrides(machine="mom3")))
    ctrl = ros_graph.add_node(ControllerNode(context=ctx, parameter_overrides=overrides(
        machine="mom3", strategy="sensor_space")))
    sim.plant.set_load([0.0, 0.0, -110.0])
    assert ros_graph.spin_until(lambda: sim.plant.k >= 800, timeout_sec=60.0)
    out = sim.plant.output()
    assert not ctrl.core.stopped, ctrl.core.stop_reason
    assert out.rigid_pose[2] - out.tool_pose[2] == pytest.approx(77e-6, rel=0.02)
    home = np.array(load_machine("mom3").model.home)
    assert np.abs(np.array(out.tool_pose) - home).max() < 1.5e-6


def _state(names, position, stamp_ns):
    msg = JointState(name=names, position=position, velocity=[0.0] * len(position), effort=[])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


@pytest.mark.ros
@pytest.mark.parametrize("position, reason", [
    ([1.0, 2.0, float("nan"), 0.5], r"position[2] (q3) is nan"),
    ([1.0, 2.0, 0.5], "position has 3 values, expected 4"),
])
def test_a_bad_state_message_stops_the_controller_and_brakes(ros_graph, position, reason):
    ctrl = ros_graph.add_node(ControllerNode(context=ros_graph.context))
    probe = ros_graph.create_node("probe")
    pub = probe.create_publisher(JointState, "drives/state", STREAM_QOS)
    estops, commands = [], []
    probe.create_subscription(Bool, "estop", lambda m: estops.append(m.data), LATCHED_QOS)
    probe.create_subscription(JointState, "drives/command", lambda m: commands.append(list(m.effort)), STREAM_QOS)
    assert ros_graph.spin_until(lambda: pub.get_subscription_count() > 0, timeout_sec=5.0)
    names = list(ARCHI.model.leg_names) if len(position) == 4 else []     # no names: checked by length
    pub.publish(_state(names, position, 0))
    assert ros_graph.spin_until(lambda: estops == [True] and commands, timeout_sec=5.0)
    assert reason in ctrl.core.stop_reason and commands[-1] == [0.0] * 4


@pytest.mark.ros
def test_the_watchdog_stops_when_the_plant_goes_silent(ros_graph):
    """sim_hw disappears mid-run: within state_timeout_s the controller is in its safe
    state with the cause reported."""
    ctx = ros_graph.context
    sim = ros_graph.add_node(SimHwNode(context=ctx, parameter_overrides=overrides(publish_markers=False)))
    ctrl = ros_graph.add_node(ControllerNode(context=ctx, parameter_overrides=overrides(state_timeout_s=0.2)))
    assert ros_graph.spin_until(lambda: sim.plant.k >= 100, timeout_sec=30.0)
    ros_graph.executor.remove_node(sim)
    sim.destroy_node()
    assert ros_graph.spin_until(lambda: ctrl.core.stopped, timeout_sec=5.0)
    assert ctrl.core.stop_reason == "drives/state: none for 0.2 s"


@pytest.mark.ros
@pytest.mark.parametrize("end_time_s", [0.1, 0.0])
def test_the_end_of_the_run_is_not_a_silent_plant(ros_graph, end_time_s):
    """sim_hw stops after its last step; told the run's end (end_time_s, the scenario's
    duration), the controller takes the silence after that state for the end of the run.
    Without it, its watchdog trips: under load the graph's shutdown came later than
    state_timeout_s, and a complete run ended "tripped" (a flaky full test run)."""
    ctx = ros_graph.context
    sim = ros_graph.add_node(SimHwNode(context=ctx, parameter_overrides=overrides(
        publish_markers=False, duration_s=0.1, shutdown_on_finish=False)))
    ctrl = ros_graph.add_node(ControllerNode(context=ctx, parameter_overrides=overrides(
        state_timeout_s=0.2, end_time_s=end_time_s)))
    assert ros_graph.spin_until(lambda: sim.finished, timeout_sec=30.0)
    ros_graph.spin_until(lambda: ctrl.core.stopped, timeout_sec=0.8)
    if end_time_s:
        assert not ctrl.core.stopped and ctrl.loop.run_ended, ctrl.core.stop_reason
    else:
        assert ctrl.core.stopped and ctrl.core.stop_reason == "drives/state: none for 0.2 s"


@pytest.mark.ros
@pytest.mark.parametrize("lost", ["command", "state", "struts"])
def test_a_message_lost_in_transport_does_not_stop_the_lockstep(ros_graph, lost):
    """A reliable sample lost in transport waits for DDS's next heartbeat (seconds): a
    lost command, state or Gough reading used to stall the lockstep until the
    controller's 0.5 s state watchdog tripped ("drives/state: none for 0.5 s", the
    flaky graph test). sim_hw now repeats an unanswered state after 0.1 s and the
    controller re-sends the answer it already gave."""
    ctx = ros_graph.context
    sim = ros_graph.add_node(SimHwNode(context=ctx, parameter_overrides=overrides(machine="mom3",
                                                                                publish_markers=False)))
    ros_graph.add_node(GoughSensorNode(context=ctx, parameter_overrides=overrides(machine="mom3")))
    ctrl = ros_graph.add_node(ControllerNode(context=ctx, parameter_overrides=overrides(
        machine="mom3", strategy="sensor_space")))
    dropped = []

    def drop_once(publish, stamp_of):
        def wrapper(data):
            if not dropped and stamp_of(data) == 100 * 1_000_000:
                dropped.append(True)
                return None
            return publish(data)
        return wrapper
    from pkm_common.cdr import stamp_ns_of
    if lost == "command":
        ctrl.publish_command = drop_once(ctrl.publish_command, stamp_ns_of)
    elif lost == "state":
        sim.pub_state.publish = drop_once(sim.pub_state.publish, stamp_ns_of)
    else:
        gough = next(n for n in ros_graph.executor.get_nodes() if isinstance(n, GoughSensorNode))
        gough.publish_struts = drop_once(gough.publish_struts, stamp_ns_of)
    assert ros_graph.spin_until(lambda: sim.plant.k >= 400 or ctrl.core.stopped, timeout_sec=60.0)
    assert dropped and not ctrl.core.stopped, ctrl.core.stop_reason
    assert sim.counts["state_repeats"] >= 1
    assert sim.plant.k >= 400 and not sim.plant.stopped
    if lost == "command":
        assert ctrl.loop.commands_resent >= 1


@pytest.mark.ros
def test_a_stopped_controller_keeps_saying_so(ros_graph):
    """controller/status is volatile: a reader that matched after the stop, or lost its
    one message, learns of the stop only from a later status. A stopped controller
    used to go silent (its status counted control cycles, and a stopped one has none):
    the operator panel, matched late, still showed "holding" and offered a jog."""
    ctrl = ros_graph.add_node(ControllerNode(context=ros_graph.context,
                                             parameter_overrides=overrides(status_decimation=10)))
    probe = ros_graph.create_node("probe")
    pub = probe.create_publisher(JointState, "drives/state", STREAM_QOS)
    estop = probe.create_publisher(Bool, "estop", LATCHED_QOS)
    modes, commands = [], []
    probe.create_subscription(DiagnosticArray, "controller/status",
                              lambda m: modes.extend(kv.value for s in m.status for kv in s.values
                                                     if kv.key == "mode"), STREAM_QOS)
    probe.create_subscription(JointState, "drives/command", lambda m: commands.append(m), STREAM_QOS)
    assert ros_graph.spin_until(lambda: pub.get_subscription_count() > 0 and estop.get_subscription_count() > 0
                                and ctrl.pub_status.get_subscription_count() > 0, timeout_sec=5.0)
    names, home = list(ARCHI.model.leg_names), ARCHI.model.inverse_kinematics(ARCHI.model.home).tolist()
    period_ns = 1_000_000

    def step(k: int) -> None:
        pub.publish(_state(names, home, k * period_ns))
        assert ros_graph.spin_until(lambda: len(commands) > k, timeout_sec=5.0), f"no answer to state {k}"

    for k in range(5):                   # 5 cycles: the stop falls between two decimated statuses
        step(k)
    estop.publish(Bool(data=True))
    assert ros_graph.spin_until(lambda: ctrl.core.stopped, timeout_sec=5.0)
    stopped_at = len(modes)
    for k in range(5, 45):
        step(k)
    ros_graph.spin_until(lambda: False, timeout_sec=0.2)
    after = modes[stopped_at:]
    assert after.count("stopped") >= 3 and set(after) == {"stopped"}, modes
    assert len(after) <= 6, f"a stopped controller floods its status: {len(after)} in 40 answers"


@pytest.mark.ros
def test_a_second_publisher_of_drive_states_stops_the_controller_naming_it(ros_graph):
    """Nothing but its plant may feed the controller: states from another node would
    move the machine through the controller's answers. The rogue here never sends a
    state; publishing on the topic is enough (as for the plant's drives/command)."""
    ctrl = ros_graph.add_node(ControllerNode(context=ros_graph.context,
                                             parameter_overrides=overrides(state_source="/plant")))
    plant = ros_graph.create_node("plant")
    pub = plant.create_publisher(JointState, "drives/state", STREAM_QOS)
    commands = []
    plant.create_subscription(JointState, "drives/command", lambda m: commands.append(m), STREAM_QOS)
    assert ros_graph.spin_until(lambda: pub.get_subscription_count() > 0, timeout_sec=5.0)
    names, home = list(ARCHI.model.leg_names), ARCHI.model.inverse_kinematics(ARCHI.model.home).tolist()
    for k in range(5):
        pub.publish(_state(names, home, k * 1_000_000))
        assert ros_graph.spin_until(lambda: len(commands) > k, timeout_sec=5.0), f"no answer to state {k}"
    ros_graph.spin_until(lambda: False, timeout_sec=0.3)          # a few graph checks: nothing found
    assert not ctrl.core.stopped, ctrl.core.stop_reason
    rogue = ros_graph.create_node("rogue")
    rogue.create_publisher(JointState, "drives/state", STREAM_QOS)
    assert ros_graph.spin_until(lambda: ctrl.core.stopped, timeout_sec=5.0)
    assert ctrl.core.stop_cause == TripCause.INTRUDER, ctrl.core.stop_reason
    assert ros_graph.spin_until(lambda: ctrl.loop.summary()["intruder"] == "/rogue", timeout_sec=5.0)
    assert ctrl.core.stop_reason in ("/rogue publishes on drives/state (only /plant may)",
                                     "2 publishers on drives/state (only /plant may)"), ctrl.core.stop_reason
    pub.publish(_state(names, home, 5_000_000))                  # answered, with the brakes' zero forces
    assert ros_graph.spin_until(lambda: len(commands) > 5, timeout_sec=5.0)
    assert not any(commands[-1].effort)
