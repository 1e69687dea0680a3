"""trajectory_node in-process: an accepted program is published (latched), a bad one
refused with a line-numbered or limit-naming diagnostic and nothing published."""

import math

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.parameter import Parameter
from std_msgs.msg import String
from trajectory_msgs.msg import MultiDOFJointTrajectory

from pkm_common.conversions import pose_msg
from pkm_common.qos import LATCHED_QOS, STREAM_QOS
from pkm_kinematics.rotations import rotation_about_z
from pkm_trajectory.trajectory_node import TrajectoryNode

pytestmark = pytest.mark.ros

PROGRAM = "G21 G90\nG1 F600 X1050 Y-400\nG3 X1050 Y-350 I0 J25\nG1 X1000 C90\nG0 X1000 Y-400 C45\nM2\n"


def test_accepts_a_program_and_refuses_bad_ones(ros_graph):
    node = ros_graph.add_node(TrajectoryNode(context=ros_graph.context, parameter_overrides=[
        Parameter("machine", value="archi"), Parameter("rate_hz", value=200.0)]))
    client = ros_graph.create_node("client")
    trajectories, diags = [], []
    client.create_subscription(MultiDOFJointTrajectory, "trajectory", trajectories.append, LATCHED_QOS)
    client.create_subscription(DiagnosticArray, "diagnostics", diags.append, STREAM_QOS)
    program = client.create_publisher(String, "program", STREAM_QOS)
    goal = client.create_publisher(PoseStamped, "goal", STREAM_QOS)
    assert ros_graph.spin_until(lambda: program.get_subscription_count() > 0)
    program.publish(String(data=PROGRAM))
    assert ros_graph.spin_until(lambda: len(trajectories) == 1)
    traj = trajectories[0]
    last = traj.points[-1].transforms[0]
    assert (last.translation.x, last.translation.y) == pytest.approx((1.0, -0.4))
    assert 2.0 * math.atan2(last.rotation.z, last.rotation.w) == pytest.approx(math.pi / 4)
    assert traj.points[1].time_from_start.nanosec == 5_000_000       # 200 Hz

    program.publish(String(data="G1 F600 X1050\nG5 X1\n"))           # unsupported word
    program.publish(String(data="G1 F600 Y-1300\nM2\n"))            # out of the workspace (and of reach)
    assert ros_graph.spin_until(lambda: node.rejected == 2)

    def errors():
        return [s.message for d in diags for s in d.status if s.level == DiagnosticStatus.ERROR]
    assert ros_graph.spin_until(lambda: len(errors()) == 2)
    messages = errors()
    assert any("line 2" in m and "G5" in m for m in messages)
    # refused with its line before anything is planned (it travelled 420 mm before a trip)
    assert any(m == "program rejected: line 1: y would reach -1.3, outside the workspace [-0.6, -0.25]"
               for m in messages), messages

    goal.publish(pose_msg([1.1, -0.35, 0.0], rotation_about_z(2.0), 0, "world"))
    assert ros_graph.spin_until(lambda: len(trajectories) == 2)
    assert node.accepted == 2 and node.pose == pytest.approx([1.1, -0.35, 2.0])


def test_a_hexapod_program_is_published_as_poses_and_twists(ros_graph):
    """genhexkins (6 task DOF): a program with A B C is published with each point's
    rotation as a quaternion and its angular velocity and acceleration as twists in the
    base frame. References: the quaternion of the program's end angles; the angular
    velocity from finite differences of the published rotations (R_k+1 R_k-1^T =
    exp(2 dt [w])); the angle rates recovered by task_space.angle_rates."""
    import numpy as np
    from pkm_kinematics import load_machine
    from pkm_kinematics.rotations import log_so3, quaternion_from_rotation, rotation_from_quaternion, \
        rotation_from_rpy
    from pkm_kinematics.task_space import angle_rates
    node = ros_graph.add_node(TrajectoryNode(context=ros_graph.context, parameter_overrides=[
        Parameter("machine", value="genhexkins"), Parameter("rate_hz", value=500.0)]))
    client = ros_graph.create_node("client")
    trajectories = []
    client.create_subscription(MultiDOFJointTrajectory, "trajectory", trajectories.append, LATCHED_QOS)
    program = client.create_publisher(String, "program", STREAM_QOS)
    assert ros_graph.spin_until(lambda: program.get_subscription_count() > 0)
    program.publish(String(data="G21 G90 G1 F1200 X10 Y-5 Z515 A4 B-3 C10\nM2\n"))
    assert ros_graph.spin_until(lambda: len(trajectories) == 1)
    points = trajectories[0].points
    end = points[-1].transforms[0]
    q_end = [end.rotation.x, end.rotation.y, end.rotation.z, end.rotation.w]
    expected = quaternion_from_rotation(rotation_from_rpy(*np.radians([4.0, -3.0, 10.0])))
    np.testing.assert_allclose(q_end, expected, atol=1e-12)
    assert (end.translation.x, end.translation.y, end.translation.z) == pytest.approx((0.010, -0.005, 0.515))
    rotations = [rotation_from_quaternion([p.transforms[0].rotation.x, p.transforms[0].rotation.y,
                                           p.transforms[0].rotation.z, p.transforms[0].rotation.w]) for p in points]
    k, dt = len(points) // 3, 1.0 / 500.0
    omega = log_so3(rotations[k + 1] @ rotations[k - 1].T) / (2.0 * dt)
    w = points[k].velocities[0].angular
    np.testing.assert_allclose([w.x, w.y, w.z], omega, rtol=1e-3, atol=1e-6)
    assert np.linalg.norm(omega) > 0.01
    angles = np.array(node.model.task_coordinates(np.zeros(3), rotations[k])[3:])
    rates, _ = angle_rates(angles, [w.x, w.y, w.z], [0.0, 0.0, 0.0])
    ratio = rates / np.radians([4.0, -3.0, 10.0])         # a straight line: every angle at the same pace
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)
    assert load_machine("genhexkins").model.task_space.dof == 6


def test_a_goal_the_controller_refused_does_not_move_the_planners_pose(ros_graph):
    """The controller's verdicts on controller/events: a refused goal's end is dropped
    (it moved the planner's pose: the next plan started where the machine was not); an
    accepted one's kept."""
    import json

    from pkm_common.qos import EVENTS_QOS
    node = ros_graph.add_node(TrajectoryNode(context=ros_graph.context, parameter_overrides=[
        Parameter("machine", value="archi"), Parameter("rate_hz", value=200.0)]))
    client = ros_graph.create_node("client")
    trajectories = []
    client.create_subscription(MultiDOFJointTrajectory, "trajectory", trajectories.append, LATCHED_QOS)
    goal = client.create_publisher(PoseStamped, "goal", STREAM_QOS)
    events = client.create_publisher(String, "controller/events", EVENTS_QOS)
    assert ros_graph.spin_until(lambda: goal.get_subscription_count() > 0 and events.get_subscription_count() > 0)
    home = list(node.pose)

    def verdict(ok: bool) -> None:
        count = len(node.chain.pending)
        events.publish(String(data=json.dumps({"kind": "trajectory", "ok": ok, "after_ns": 1, "message": ""})))
        assert ros_graph.spin_until(lambda: len(node.chain.pending) < count)

    goal.publish(pose_msg([1.01, -0.4, 0.0], rotation_about_z(home[2]), 0, "world"))
    assert ros_graph.spin_until(lambda: len(trajectories) == 1)
    assert node.pose == pytest.approx([1.01, -0.4, home[2]])        # chained while awaiting the verdict
    verdict(False)
    assert node.pose == pytest.approx(home)                          # refused: back where the machine is
    goal.publish(pose_msg([1.0, -0.39, 0.0], rotation_about_z(home[2]), 0, "world"))
    assert ros_graph.spin_until(lambda: len(trajectories) == 2)
    start = trajectories[1].points[0].transforms[0].translation
    assert (start.x, start.y) == pytest.approx(tuple(home[:2]))      # planned from home, not from x = 1.01
    verdict(True)
    assert node.pose == pytest.approx([1.0, -0.39, home[2]])


def test_a_goal_or_program_from_a_node_the_run_did_not_name_is_refused(ros_graph):
    """A rogue node moved the tool through goal (+5 mm) and program (G91 G1 Y5): with
    the run's operators named, both are refused with its name, nothing is planned."""
    node = ros_graph.add_node(TrajectoryNode(context=ros_graph.context, parameter_overrides=[
        Parameter("machine", value="archi"), Parameter("operator_sources", value="/panel, /bringup_monitor")]))
    rogue = ros_graph.create_node("rogue")
    trajectories, diags = [], []
    rogue.create_subscription(MultiDOFJointTrajectory, "trajectory", trajectories.append, LATCHED_QOS)
    rogue.create_subscription(DiagnosticArray, "diagnostics", diags.append, STREAM_QOS)
    program = rogue.create_publisher(String, "program", STREAM_QOS)
    goal = rogue.create_publisher(PoseStamped, "goal", STREAM_QOS)
    assert ros_graph.spin_until(lambda: program.get_subscription_count() > 0 and goal.get_subscription_count() > 0
                                and node.pub_diag.get_subscription_count() > 0)
    program.publish(String(data="G91 G1 F600 Y5\n"))
    goal.publish(pose_msg([1.005, -0.4, 0.0], rotation_about_z(0.7), 0, "world"))
    assert ros_graph.spin_until(lambda: node.refused_senders == 2)
    def errors():
        return [s for d in diags for s in d.status if s.level == DiagnosticStatus.ERROR]
    assert ros_graph.spin_until(lambda: len(errors()) == 2)
    refusals = errors()
    assert {s.message.split(":")[0] for s in refusals} == {"program refused", "goal refused"}
    assert all("/rogue publishes on" in s.message and "operator_sources" in s.message for s in refusals)
    assert all({kv.key: kv.value for kv in s.values}["intruder"] == "/rogue" for s in refusals)
    ros_graph.spin_until(lambda: False, timeout_sec=0.3)
    assert trajectories == [] and node.accepted == 0


def test_a_program_planned_at_start_up_is_signed_and_published_at_the_runs_start(ros_graph, tmp_path):
    """pkm-run starts the planner with the other nodes (wait_for_start): its program is
    planned at once but held; a start signal without the run's credential is refused;
    at the run's start it is signed then, so that a controller that started after the
    plan (its Verifier refuses what was signed before it was made) takes it."""
    from pkm_common.credential import RunKey, Signer, Verifier
    from rclpy.serialization import serialize_message
    key = RunKey.create(tmp_path / "credential.key")
    program = tmp_path / "p.nc"
    program.write_text(PROGRAM)
    node = ros_graph.add_node(TrajectoryNode(context=ros_graph.context, parameter_overrides=[
        Parameter("machine", value="archi"), Parameter("rate_hz", value=200.0),
        Parameter("program_file", value=str(program)), Parameter("wait_for_start", value=True),
        Parameter("credential_file", value=str(tmp_path / "credential.key"))]))
    assert node.held is not None and node.accepted == 0          # planned, not published
    controller_checks = Verifier(key)                               # a controller that came up after the plan
    client = ros_graph.create_node("client")
    raw = []
    client.create_subscription(MultiDOFJointTrajectory, "trajectory", raw.append, LATCHED_QOS, raw=True)
    start = client.create_publisher(String, "run/start", LATCHED_QOS)
    assert ros_graph.spin_until(lambda: start.get_subscription_count() > 0)
    start.publish(serialize_message(String(data="start")))          # no credential: refused
    ros_graph.spin_until(lambda: bool(raw), timeout_sec=0.5)
    assert not raw and node.held is not None
    start.publish(Signer(key, "/client").text("run/start", "start"))
    assert ros_graph.spin_until(lambda: len(raw) == 1)
    assert node.held is None and node.accepted == 1
    sender, refused = controller_checks.check("trajectory", raw[0], True)
    assert refused is None and sender == node.get_fully_qualified_name(), refused


def test_a_runs_program_the_planner_rejects_ends_the_planner_naming_why(ros_graph, tmp_path):
    """Under pkm-run (wait_for_start) a rejected program_file is the run's failure at
    once (the node refuses its configuration: pkm-run reports it), not a controller
    waiting for a trajectory until the run's timeout."""
    program = tmp_path / "p.nc"
    program.write_text("G21 G90\nG1 F600 Y-1300\nM2\n")               # out of the workspace
    with pytest.raises(ValueError, match="program_file rejected: line 2: y would reach -1.3"):
        TrajectoryNode(context=ros_graph.context, parameter_overrides=[
            Parameter("machine", value="archi"), Parameter("program_file", value=str(program)),
            Parameter("wait_for_start", value=True)])
