"""``trajectory_node``: goals and G-code programs in, validated trajectories out.

Thin shell over planner.py and program.py. A ``goal`` (PoseStamped, tool pose in
world) plans a point-to-point move from the end of the last trajectory (or the
machine's home); a ``program`` (std_msgs/String, G-code) plans the program from
there; ``program_file`` (parameter) is planned at start, and with ``wait_for_start``
(pkm-run's runs) held until the run's signed start signal (``run/start``), then
signed and published; a rejected ``program_file`` of a run ends the node (its run
cannot start). Before anything is
published the whole trajectory is checked against the machine model (reachability,
joint limits, joint velocity and acceleration, conditioning, transmission factors);
a rejected one publishes nothing and reports which sample, which limit and by how
much on ``diagnostics`` (ERROR). With ``credential_file`` (the run's key) a goal or
program without the run's credential is refused, and the trajectories carry it
(pkm_common.credential). An accepted one goes out on ``trajectory``
(MultiDOFJointTrajectory, one joint "tool", latched) and is reported OK.
"""

from __future__ import annotations

from pathlib import Path

from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from std_msgs.msg import String

from pkm_common import topics
from pkm_common.cdr import decode_string
from pkm_common.conversions import (diagnostic_array, diagnostic_status, graph_senders, pose_from_msg,
                                    trajectory_bytes)
from pkm_common.credential import RunKey, Signer, Verifier, split_text
from pkm_common.endpoints import publisher, subscription
from pkm_common.params import declare_bool, declare_str
from pkm_common.poses import tool_pose_to_machine
from pkm_common.runner import main_exit, run_node
from pkm_common.sources import AllowedSenders, CommandGuard, node_names
from pkm_trajectory.planner import point_to_point
from pkm_trajectory.plan_chain import PlanChain, trajectory_verdict
from pkm_trajectory.planning import declare_planner
from pkm_trajectory.program import program_events_text


class TrajectoryNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("trajectory", context=context, **kwargs)
        self.settings = settings = declare_planner(self)
        self.config = settings.config
        self.model = self.config.model
        self.space = self.model.task_space
        program_file = settings.program_file
        # plans start where the controller's accepted trajectories end (plan_chain)
        self.chain = PlanChain(self.model.home)
        self.accepted = self.rejected = 0
        # who may send goals and programs (pkm_common.sources; pkm-run names them, empty: anyone)
        operators = node_names(declare_str(self, "operator_sources", "", "full node names allowed to send goals "
                                           "and programs, comma-separated (empty: anyone)", allow_empty=True))
        # the run's key: goals and programs carry its credential, and so do our trajectories
        path = declare_str(self, "credential_file", "", "the run's key (pkm_common.credential; empty: commands "
                           "need none)", allow_empty=True)
        key = RunKey.read(path) if path else None
        # pkm-run starts the planner with the other nodes: its program is planned at once
        # but signed and published at the run's start, when the controller that checks the
        # credential is up (a controller refuses a credential signed before it started).
        # The start's check is made before any publisher: pkm-run signs the start once it
        # sees this node's trajectory publisher, and a Verifier refuses what was signed
        # before it was made
        self.held = None                   # the program's plan until the start
        self.wait_for_start = declare_bool(self, "wait_for_start", False, "hold the program's trajectory until "
                                           "the run's start signal (run/start, from operator_sources)")
        self.started = not self.wait_for_start
        self.start_guard = CommandGuard(AllowedSenders(topics.RUN_START, operators, "operator_sources"), Verifier(key))
        self.pub = publisher(self, topics.TRAJECTORY)
        self.pub_diag = publisher(self, topics.DIAGNOSTICS)
        self.pub_events = publisher(self, topics.PROGRAM_EVENTS)
        self.signer = Signer(key, self.get_fully_qualified_name()) if key else None
        self.command_guards = {topic: CommandGuard(AllowedSenders(topic, operators, "operator_sources"), Verifier(key))
                       for topic in (topics.GOAL, topics.PROGRAM)}
        self.refused_senders = 0
        self.inputs = {topics.GOAL: subscription(self, topics.GOAL, self.on_goal, raw=True),
                       topics.PROGRAM: subscription(self, topics.PROGRAM, self.on_program, raw=True)}
        self.controller = AllowedSenders(topics.CONTROLLER_EVENTS, node_names(declare_str(
            self, "controller_source", "", "the controller's full node name: its verdicts move where plans start "
            "(empty: anyone's)", allow_empty=True)), "controller_source")
        self.events_sub = subscription(self, topics.CONTROLLER_EVENTS, self.on_event)
        if not self.started:
            self.inputs[topics.RUN_START] = subscription(self, topics.RUN_START, self.on_start, raw=True)
        if program_file:
            self.submit("program_file", lambda: settings.plan_program(Path(program_file).read_text(), self.pose))

    @property
    def pose(self) -> list:
        """Where the next plan starts."""
        return self.chain.start()

    def on_event(self, msg: String) -> None:
        verdict = trajectory_verdict(msg.data)
        if verdict is None:
            return
        if self.controller.allowed:       # a verdict only from the run's controller (names only)
            found = self.controller.check(graph_senders(self, self.events_sub.topic_name))
            if found is not None:
                self.get_logger().error(f"verdict ignored: {found.reason}")
                return
        ok, stamp_ns = verdict
        if self.chain.verdict(ok, stamp_ns) and not ok:
            self.get_logger().warning(f"the controller refused the trajectory: plans start at {self.pose} again")

    def sender_refused(self, topic: str, buf: bytes) -> bool:
        """A goal or program without the run's credential of an allowed sender, or while
        a node the run did not name publishes on its topic: refused, reported with the
        sender (diagnostics, recorded), counted."""
        found = self.command_guards[topic].refused(lambda: graph_senders(self, self.inputs[topic].topic_name), buf)
        if found is None:
            return False
        self.refused_senders += 1
        self.get_logger().error(f"{topic} refused: {found.reason}")
        self.report(2, f"{topic} refused: {found.reason}", {"intruder": found.sender})
        return True

    def on_goal(self, buf: bytes) -> None:
        if self.sender_refused(topics.GOAL, buf):
            return

        def plan():
            msg = deserialize_message(buf, PoseStamped)
            position, rotation = pose_from_msg(msg)
            # a planar machine's yaw on the revolution it is at (a 6-DOF pose: its roll, pitch, yaw)
            target = tool_pose_to_machine(self.space, position, rotation, self.pose[2])
            return self.settings.plan([point_to_point(self.pose, target)])
        self.submit("goal", plan)

    def on_start(self, buf: bytes) -> None:
        found = self.start_guard.refused(lambda: graph_senders(self, self.inputs[topics.RUN_START].topic_name), buf)
        if found is not None:
            self.refused_senders += 1
            self.get_logger().error(f"start refused: {found.reason}")
            self.report(2, f"start refused: {found.reason}", {"intruder": found.sender})
            return
        self.started = True
        if self.held is not None:
            self.publish(*self.held)
            self.held = None

    def on_program(self, buf: bytes) -> None:
        if self.sender_refused(topics.PROGRAM, buf):
            return
        self.submit("program", lambda: self.settings.plan(self.settings.program_segments(
            split_text(decode_string(buf, "program"))[1], self.pose)))

    def submit(self, source: str, plan) -> None:
        """Plan (``plan()``: planning.PlannerSettings's, validated), publish or refuse;
        every outcome is reported."""
        try:
            samples = plan()
        except Exception as exc:              # noqa: BLE001 - every failure is a reported rejection
            self.rejected += 1
            self.get_logger().error(f"{source} rejected: {exc}")
            self.report(2, f"{source} rejected: {exc}", {})
            if source == "program_file" and self.wait_for_start:      # a run's program: its run cannot start
                raise ValueError(f"program_file rejected: {exc}") from None
            return
        if source == "program_file" and not self.started:
            self.held = (source, samples)
            self.get_logger().info(f"{source} planned: {samples.duration_s:.3f} s, held until the start")
            return
        self.publish(source, samples)

    def publish(self, source: str, samples) -> None:
        """An accepted plan, signed now, to the controller; reported."""
        stamp_ns = self.get_clock().now().nanoseconds
        self.pub.publish(trajectory_bytes(self.space, samples.time_s, samples.position, samples.velocity,
                                          samples.acceleration, stamp_ns, self.signer))
        self.chain.published(samples.position[-1].tolist(), stamp_ns)
        if samples.events:                 # spindle, coolant, tool changes at their times along it
            self.pub_events.publish(String(data=program_events_text(stamp_ns, samples.events)))
        self.accepted += 1
        self.get_logger().info(f"{source} accepted: {samples.duration_s:.3f} s, {len(samples.time_s)} points")
        self.report(0, f"{source} accepted", {"duration_s": samples.duration_s, "points": len(samples.time_s)})

    def report(self, level: int, message: str, values: dict) -> None:
        values = {**values, "accepted": self.accepted, "rejected": self.rejected,
                  "refused_senders": self.refused_senders}
        self.pub_diag.publish(diagnostic_array(self.get_clock().now().to_msg(),
                                               [diagnostic_status("trajectory", level, message, values)]))


def main(args=None):
    main_exit(run_node(TrajectoryNode, args=args, name="trajectory"))


if __name__ == "__main__":
    main()
