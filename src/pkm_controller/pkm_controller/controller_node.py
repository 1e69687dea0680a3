"""``controller_node``: the redundant-actuation controller as a lifecycle node (thin
shell over controller.ControllerCore).

configure: read and validate the parameters (config/controller/*.yaml); a bad one
fails the transition with its name and allowed range. activate: answer every
``drives/state`` (and, for the metrology strategies, the ``metrology/struts`` or
``metrology/pose`` of the same stamp) with ``drives/command`` stamped like the state
(lockstep). ``trajectory`` (latched) starts at the next state; with
``wait_for_trajectory`` / ``wait_for_start`` no state is answered before the
trajectory / a latched ``run/start`` (an orchestrator's start signal); ``estop`` and every
trip of the supervisor put the controller in its safe state (zero forces) and latch
``estop`` so the drives brake. A wall-clock watchdog trips when ``drives/state`` or
the metrology stops for ``state_timeout_s`` / ``metrology_timeout_s``, from the
first state answered, until the state of ``end_time_s`` (the run's last step, after
which the plant is silent by design; 0: no known end). (DDS deadline
QoS would need the publisher to offer a deadline too; sim_hw in lockstep publishes
only when answered, so a timer on the controller's side is the same test.)
With ``autostart`` (default) the node configures and activates itself.
"""

from __future__ import annotations

import json
import time
from dataclasses import fields

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import TransitionCallbackReturn
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, String
from trajectory_msgs.msg import MultiDOFJointTrajectory

from pkm_common.causes import TripCause, plant_stop_cause, setpoint_held
from pkm_common.cdr import (JointStateDecoder, JointStateEncoder, PoseStampedEncoder, decode_multidof_trajectory,
                            decode_pose_stamped, in_order)
from pkm_common.conversions import diagnostic_array, diagnostic_status, machine_pose_components, ns_to_stamp
from pkm_common.node_tap import NodeTap
from pkm_common.params import declare_bool, declare_like
from pkm_common.qos import EVENTS_QOS, LATCHED_QOS, STREAM_PUBLISHER_QOS, STREAM_QOS
from pkm_common.runner import main_exit, run_node
from pkm_common.timing import DurationHistogram
from pkm_controller.controller import ControllerConfig
from pkm_controller.configuration import core_from_parameters, metrology_inputs, run_summary, warm_up
from pkm_controller.lockstep import StampPairing
from pkm_controller.operator import Action, OperatorInbox, apply_action, event_json, event_summary
from pkm_controller.strategies import Feedback
from pkm_controller.reference import reference_from_trajectory

NODE_PARAMETERS = {"machine": "archi", "state_timeout_s": 0.5, "metrology_timeout_s": 0.5,
                   "status_decimation": 100, "summary_path": "", "wait_for_trajectory": False,
                   "wait_for_start": False, "end_time_s": 0.0}


class ControllerNode(LifecycleNode):
    def __init__(self, context=None, **kwargs):
        super().__init__("controller", context=context, **kwargs)
        self.core = None
        self.active = False
        self.entities = []
        self.compute_s = DurationHistogram()     # prepare + complete per cycle (constant memory)
        self.response_s = DurationHistogram()    # last input (state or metrology) -> command ready
        self.prepare_s = 0.0
        self.was_stopped = False
        self.configure_error = ""
        self.trajectory_accepted = False
        self.start_received = False    # run/start (latched Bool) from an orchestrator
        self.answers_published = 0     # drives/command and controller/reference, one each per answer
        self.last_answer = (None, b"")  # (stamp, command bytes): sent again when the sim repeats the state
        self.commands_resent = 0
        self.inbox = OperatorInbox()   # an operator's actions, applied after the next answer
        self.tap = NodeTap(self, declare_bool(self, "tap", False, "copy drives/command and controller/reference "
                                              "to a recorder in batches (pkm_common.tap)"))
        if declare_bool(self, "autostart", True, "configure and activate at start"):
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise ValueError(self.configure_error)
            self.trigger_activate()

    # ------------------------------------------------------------- lifecycle
    def _read_parameters(self) -> tuple[dict, ControllerConfig]:
        values = {name: declare_like(self, name, default) for name, default in NODE_PARAMETERS.items()}
        config = {f.name: declare_like(self, f.name, f.default) for f in fields(ControllerConfig)}
        return values, ControllerConfig(**config)

    def on_configure(self, state) -> TransitionCallbackReturn:
        try:
            values, config = self._read_parameters()
            self.core = core_from_parameters(values["machine"], config)
            warm_up(self.core)              # the kernels loaded now, not in the first cycles
        except ValueError as exc:
            self.configure_error = str(exc)
            self.get_logger().error(f"configure refused: {exc}")
            return TransitionCallbackReturn.FAILURE
        self.values = values
        # the run's last step (the plant stops publishing after it): once its state is
        # here, silence is the end of the run, not a fault (0: no known end)
        end_s = float(values["end_time_s"])
        self.end_ns = round((end_s - 0.5 * config.dt_s) * 1e9) if end_s > 0.0 else 0
        self.run_ended = False
        self.names = self.core.names
        strategy = self.core.strategy
        self.wait_for = strategy.reading          # "struts", "pose", or "" for the encoder strategies
        self.pairing = StampPairing(strategy.uses_metrology, strategy.reading)
        struts = strategy.feedback == Feedback.STRUTS
        # the per-step streams as bytes (pkm_common.cdr): rclpy message objects cost
        # ~30-50 us to take and ~13 us to publish each, more than most control laws
        self.state_decoder = JointStateDecoder("drives/state")
        self.command_encoder = JointStateEncoder(self.names, fields=("effort",))
        self.reference_encoder = PoseStampedEncoder("world")
        self.decode_metrology = JointStateDecoder("metrology/struts").decode if struts else \
            (lambda buf: decode_pose_stamped(buf, "metrology/pose"))
        self.pub_command = self.create_publisher(JointState, "drives/command", STREAM_PUBLISHER_QOS)
        self.pub_reference = self.create_publisher(PoseStamped, "controller/reference", STREAM_PUBLISHER_QOS)
        self.publish_command = self.tap.wrap(self.pub_command, JointState).publish
        self.publish_reference_bytes = self.tap.wrap(self.pub_reference, PoseStamped).publish
        self.pub_status = self.create_publisher(DiagnosticArray, "controller/status", STREAM_PUBLISHER_QOS)
        self.pub_estop = self.create_publisher(Bool, "estop", LATCHED_QOS)
        self.pub_events = self.create_publisher(String, "controller/events", EVENTS_QOS)
        self.entities = [self.pub_command, self.pub_reference, self.pub_status, self.pub_estop, self.pub_events,
                         self.create_subscription(Float64, "controller/feed_override",
                                                  lambda m: self.operator(Action.FEED_OVERRIDE, m.data), STREAM_QOS),
                         self.create_subscription(String, "controller/settings",
                                                  lambda m: self.operator(Action.SETTINGS, m.data), STREAM_QOS),
                         self.create_subscription(JointState, "drives/state", self.on_state, STREAM_QOS,
                                                  raw=True),
                         self.create_subscription(MultiDOFJointTrajectory, "trajectory", self.on_trajectory,
                                                  LATCHED_QOS, raw=True),
                         self.create_subscription(Bool, "estop", self.on_estop, LATCHED_QOS),
                         self.create_subscription(Bool, "run/start", self.on_start, LATCHED_QOS),
                         self.create_timer(0.01, self.on_watchdog)]
        if strategy.uses_metrology:
            self.entities.append(self.create_subscription(JointState if struts else PoseStamped,
                                                          strategy.metrology_topic, self.on_metrology, STREAM_QOS,
                                                          raw=True))
        self.get_logger().info(f"configured: {values['machine']}, {config.strategy}, {config.distribution}")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.active = True
        self.pairing.reset_watchdog()
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.active = False
        self.safe_stop("deactivated", TripCause.DEACTIVATED)
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._destroy_entities()
        self.core = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        self._destroy_entities()
        return TransitionCallbackReturn.SUCCESS

    def _destroy_entities(self) -> None:
        for entity in self.entities:
            for destroy in (self.destroy_publisher, self.destroy_subscription, self.destroy_timer):
                if destroy(entity):
                    break
        self.entities = []

    # ----------------------------------------------------------------- inputs
    def on_state(self, buf: bytes) -> None:
        if not self.active:
            return
        if (not self.trajectory_accepted and self.values["wait_for_trajectory"]) or \
                (not self.start_received and self.values["wait_for_start"]):
            return                     # a scripted run starts at its first state, deterministically
        # the watchdog is armed from the first state answered: before its start the
        # sim only repeats step 0 for discovery, and on a loaded machine a pause in
        # those repeats tripped a run before it began (a full test run, 2 tests)
        now = time.monotonic()
        try:
            msg = self.state_decoder.decode(buf)
        except ValueError as exc:      # malformed bytes from a raw publisher
            if not self.core.stopped:
                self.safe_stop(str(exc), TripCause.INPUT_REFUSED)
            return
        self.run_ended = self.run_ended or 0 < self.end_ns <= msg.stamp_ns
        plant_cause = plant_stop_cause(msg.frame_id)
        if plant_cause is not None and not self.core.stopped:
            self.safe_stop_plant(plant_cause)      # the drives' status word: the plant braked
        if not self.pairing.state_arrived(msg.stamp_ns, now):
            # a repeat: sim_hw republishes a state it has no answer for (step 0 until the
            # graph is connected; later a lost message); our answer was lost: again
            stamp, command = self.last_answer
            if stamp == msg.stamp_ns and command:
                self.pub_command.publish(command)    # not tapped: the bag holds one per stamp
                self.commands_resent += 1
            return
        start = time.perf_counter()
        prepared = self.prepare(msg)
        self.prepare_s = time.perf_counter() - start
        if prepared and self.pairing.wait_for_reading(msg):
            return                     # complete() when the metrology of this stamp arrives
        self.answer(msg.stamp_ns, start)

    def on_metrology(self, buf: bytes) -> None:
        try:
            msg = self.decode_metrology(buf)
        except ValueError as exc:
            if self.active and not self.core.stopped:
                self.safe_stop(str(exc), TripCause.INPUT_REFUSED)
            return
        state = self.pairing.reading_arrived(msg.stamp_ns, msg)
        if state is not None and self.active:
            self.answer(state.stamp_ns, time.perf_counter())

    def on_trajectory(self, buf: bytes) -> None:
        """Read from its bytes (pkm_common.cdr): rclpy's message objects of a long
        trajectory would hold the loop for tens of milliseconds."""
        try:
            ref = reference_from_trajectory(decode_multidof_trajectory(buf), self.core.model.task_space)
        except ValueError as exc:      # recorded too: the replay pairs every trajectory with its event
            self.report([apply_action(self.core, Action.TRAJECTORY, exc)])
            return
        self.operator(Action.TRAJECTORY, ref)

    def operator(self, action: Action, payload) -> None:
        """A trajectory, feed override or settings change (operator.py): applied at once
        before the first cycle, else right after the next answer (between two cycles)."""
        if self.core is not None:
            self.report(self.inbox.add(self.core, action, payload))

    def report(self, events: list) -> None:
        """Each applied or refused action: recorded on controller/events and logged."""
        for event in events:
            self.pub_events.publish(String(data=event_json(event)))
            if event["ok"]:
                self.trajectory_accepted |= event["kind"] == Action.TRAJECTORY.value
                self.get_logger().info(event_summary(event))
            else:
                self.get_logger().error(event["message"])
                self.publish_status(extra=event_summary(event))

    def on_start(self, msg: Bool) -> None:
        self.start_received = self.start_received or bool(msg.data)

    def on_estop(self, msg: Bool) -> None:
        """Stop at once, and record after which answered state (controller/events): the
        replay stops the controller at the same point, whatever order the recorder got
        the estop and the commands in."""
        if msg.data and self.core is not None and not self.core.stopped:
            self.report([apply_action(self.core, Action.ESTOP, None, after_ns=self.last_answer[0])])
            self.safe_stop("estop", TripCause.ESTOP)

    def on_watchdog(self) -> None:
        if not self.active or self.core is None or self.core.stopped or self.run_ended:
            return
        fault = self.pairing.silence_fault(time.monotonic(), self.values["state_timeout_s"],
                                           self.values["metrology_timeout_s"])
        if fault:
            self.safe_stop(fault, TripCause.WATCHDOG)

    # ----------------------------------------------------------------- output
    def prepare(self, msg) -> bool:
        """First half of the cycle on a drive state (pkm_common.cdr.JointStateData);
        False when the controller is stopped (the answer is zero forces)."""
        core = self.core
        self.was_stopped = core.stopped
        try:
            msg = in_order(msg, self.names, "drives/state")
        except ValueError as exc:
            core.trip(str(exc), TripCause.INPUT_REFUSED)
        return core.prepare(msg.stamp_ns * 1e-9, msg.position, msg.velocity, msg.effort,
                            held=setpoint_held(msg.frame_id))

    def answer(self, stamp: int, start: float) -> None:
        """Complete the prepared cycle with the metrology of ``stamp`` and publish the
        command; ``start``: when the last input arrived (the response time is timed)."""
        core = self.core
        struts = pose = None
        extra = self.pairing.take_reading(stamp)
        if not core.stopped:                      # stopped: zero forces, no metrology needed
            try:
                struts, pose = metrology_inputs(self.wait_for, extra)
            except ValueError as exc:             # NaN or a non-unit quaternion
                core.trip(str(exc), TripCause.INPUT_REFUSED)
        complete_start = time.perf_counter()
        forces = core.complete(struts=struts, metrology_pose=pose)
        end = time.perf_counter()
        self.compute_s.add(self.prepare_s + end - complete_start)
        self.response_s.add(end - start)
        command = self.command_encoder.encode(stamp, effort=forces)
        self.publish_command(command)
        self.last_answer = (stamp, command)
        self.answers_published += 1
        if core.stopped and not self.was_stopped:
            self.safe_stop(core.stop_reason, core.stop_cause)
        self.publish_reference(stamp)
        # counted in answers, not control cycles: a stopped controller has no cycles and
        # must keep saying it is stopped to a reader that matched late or lost a message
        if self.answers_published % self.values["status_decimation"] == 0:
            self.publish_status()
        if self.inbox.pending:
            self.report(self.inbox.drain(core))
        self.tap.after_cycle()

    def publish_reference(self, stamp_ns: int) -> None:
        position, orientation = machine_pose_components(self.core.space, self.core.record.reference)
        self.publish_reference_bytes(self.reference_encoder.encode(stamp_ns, position, orientation))

    def publish_status(self, extra: str = "") -> None:
        level, message, values = self.core.status()
        if extra:
            level, message = max(level, 1), f"{message}; {extra}"
        stamp = ns_to_stamp(round((self.core.last_time_s or 0.0) * 1e9))
        self.pub_status.publish(diagnostic_array(stamp, [diagnostic_status("controller", level, message, values)]))

    def safe_stop_plant(self, cause: TripCause) -> None:
        """The plant stopped on its own (its status word in drives/state): the
        controller stops with the plant's cause, not as a drive failure."""
        self.core.plant_stopped(cause)
        self.safe_stop(self.core.stop_reason, self.core.stop_cause)

    def safe_stop(self, reason: str, cause: TripCause) -> None:
        """Zero forces, brakes requested (estop latched), reported, and recorded after the
        last answered state (controller/events: the replay stops there too)."""
        if self.core is None:
            return
        self.report([apply_action(self.core, Action.SAFE_STOP, {"reason": reason, "cause": cause},
                                  after_ns=self.last_answer[0])])
        self.get_logger().error(f"safe stop: {self.core.stop_reason}")
        self.pub_estop.publish(Bool(data=True))
        self.publish_status()

    def destroy_node(self):
        if hasattr(self, "tap"):
            self.tap.close()
        path = getattr(self, "values", {}).get("summary_path")
        if path and self.core is not None:
            with open(path, "w", encoding="utf-8") as fh:
                json.dump({**run_summary(self.core, self.compute_s, self.response_s, self.answers_published),
                           "commands_resent": self.commands_resent}, fh,
                          indent=2)
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(ControllerNode, args=args, name="controller", executor="events"))


if __name__ == "__main__":
    main()
