"""What controller_node does with each message, without rclpy: the lockstep answer
to a drive state (and its metrology reading), the operator's actions, the safe stops
and the status. It works on the messages' bytes (pkm_common.cdr) and hands what goes
out to ``ports``, which the node implements with its publishers (ros2_control's
boundary: the node owns the middleware, this owns the decisions).

``ports`` is a ``ControllerPorts`` (below): what the loop sends out and asks the graph.

Its inputs have one source each, as the plant's commands do (pkm_common.sources):
``drives/state`` comes from ``state_source`` (pkm-run: the run's sim_hw) and the
metrology from ``metrology_source`` (its gough_sensor), or else from the one
publisher there is at the first state answered. Another publisher on either would
move the machine through this controller's answers: it stops it (cause intruder),
named, when its publisher matches (before its first message) or at the next check
of the graph (every ``SOURCE_CHECK_S``).

Its commands have named sources too (pkm_common.sources.AllowedSenders; empty: anyone):
``trajectory`` from ``trajectory_source`` (the run's planner), the settings, the feed
override and ``run/start`` from ``operator_sources`` (pkm-run, the panel, the nodes a
scenario names), and so the planner's ``goal`` and ``program``, which it watches. A command while another node publishes on its topic is refused,
recorded on controller/events with the intruder's name (``intruder`` key; the replay
skips it: nothing was applied) and counted; during a motion the machine stops (cause
intruder), at the command or at a check of the graph (one topic every
``COMMAND_CHECK_S``, in turn). A publisher the graph knows no node of is not
counted (sources.AllowedSenders.check says why).

Names can be spoofed: with the run's key (``credentials``, the ``credential_file``
parameter) every command message must also carry a valid credential of an allowed
sender, taken once (pkm_common.credential); one without is refused the same way,
recorded with the sender its tag claims, or ``(no credential)``.
"""

from __future__ import annotations

import time
from typing import Protocol

from pkm_common.causes import PlantStatus, TripCause, plant_status
from pkm_common.cdr import (JointStateDecoder, JointStateEncoder, PoseStampedEncoder, decode_multidof_trajectory,
                            decode_pose_stamped, decode_string, in_order, stamp_ns_of)
from pkm_common.credential import Verifier, split_text
from pkm_common.poses import machine_pose_components
from pkm_common.sources import AllowedSenders, CommandGuard, SourceGate, node_names
from pkm_common.timing import DurationHistogram

from .configuration import metrology_inputs, run_summary
from .controller import ControllerCore
from .lockstep import StampPairing
from .operator_actions import Action, OperatorInbox, apply_action, event_json, event_summary
from .reference import check_consistent, reference_from_trajectory
from .strategies import Feedback

__all__ = ["COMMAND_CHECK_S", "ControllerLoop", "ControllerPorts", "SOURCE_CHECK_S"]

SOURCE_CHECK_S = 0.1            # how often the graph is asked who publishes the inputs
COMMAND_CHECK_S = 0.025         # during a motion, one command topic asked this often (all six in 0.15 s)
NAMING_CHECKS = 40              # graph checks (one per COMMAND_CHECK_S) to name a sender refused unnamed


class ControllerPorts(Protocol):
    """What a ControllerLoop needs of its shell (controller_node implements it with its
    publishers and the graph; a replay or a study engine with recorders)."""

    def publish_command(self, command: bytes) -> None:
        """drives/command (tapped for the recorder)."""

    def resend_command(self, command: bytes) -> None:
        """The same answer again, not tapped (the bag holds one per stamp)."""

    def publish_reference_bytes(self, reference: bytes) -> None:
        """controller/reference."""

    def publish_status(self, stamp_ns: int, level: int, message: str, values: dict) -> None:
        """controller/status."""

    def publish_event(self, text: str) -> None:
        """controller/events (JSON)."""

    def publish_estop(self) -> None:
        """estop, latched true: the drives brake."""

    def after_cycle(self) -> None:
        """The end of an answer: the recording tap's moment to flush."""

    def input_publishers(self, topic: str) -> list[str]:
        """The full names of the nodes publishing an input topic, one per publisher."""

    def topic_senders(self, topic: str) -> list[str]:
        """The node names publishing a command topic (a failed graph query answers a
        name no run allows)."""

    def log_info(self, text: str) -> None: ...

    def log_error(self, text: str) -> None: ...


class ControllerLoop:
    """One configured controller's answers (the node's ``values``: its parameters
    beside ControllerConfig, config/controller/*.yaml)."""

    def __init__(self, core: ControllerCore, values: dict, ports: ControllerPorts, credentials: Verifier | None = None):
        self.core, self.values, self.ports = core, values, ports
        self.credentials = credentials or Verifier(None)     # the run's key (pkm_common.credential)
        self.active = False
        self.compute_s = DurationHistogram()     # prepare + complete per cycle (constant memory)
        self.response_s = DurationHistogram()    # last input (state or metrology) -> command ready
        self.prepare_s = 0.0
        self.was_stopped = False
        self.trajectory_accepted = False
        self.start_received = False    # run/start (latched Bool) from an orchestrator
        self.answers_published = 0     # drives/command and controller/reference, one each per answer
        self.last_answer = (None, b"")  # (stamp, command bytes): sent again when the sim repeats the state
        self.commands_resent = 0
        self.inbox = OperatorInbox()   # an operator's actions, applied after the next answer
        # the run's last step (the plant stops publishing after it): once its state is
        # here, silence is the end of the run, not a fault (0: no known end)
        end_s = float(values["end_time_s"])
        self.end_ns = round((end_s - 0.5 * core.config.dt_s) * 1e9) if end_s > 0.0 else 0
        self.run_ended = False
        self.names = core.names
        strategy = core.strategy
        self.wait_for = strategy.reading          # "struts", "pose", or "" for the encoder strategies
        self.pairing = StampPairing(strategy.uses_metrology, strategy.reading)
        struts = strategy.feedback == Feedback.STRUTS
        # the per-step streams as bytes (pkm_common.cdr): rclpy message objects cost
        # ~30-50 us to take and ~13 us to publish each, more than most control laws
        self.state_decoder = JointStateDecoder("drives/state")
        self.command_encoder = JointStateEncoder(self.names, fields=("effort",))
        self.reference_encoder = PoseStampedEncoder("world")
        # False: a shell whose controller/reference or controller/status nobody reads (a
        # direct run without a recording, pkm_bringup.direct) has none made
        self.publishes_reference = self.publishes_status = True
        self.decode_metrology = JointStateDecoder("metrology/struts").decode if struts else \
            (lambda buf: decode_pose_stamped(buf, "metrology/pose"))
        operators = node_names(values["operator_sources"])
        self.commands = {topic: CommandGuard(AllowedSenders(topic, allowed, parameter), self.credentials)
                         for topic, allowed, parameter in (
            ("trajectory", node_names(values["trajectory_source"]), "trajectory_source"),
            ("controller/settings", operators, "operator_sources"),
            ("controller/feed_override", operators, "operator_sources"),
            ("run/start", operators, "operator_sources"),
            # the planner's inputs, watched during a motion (the planner refuses their messages)
            ("goal", operators, "operator_sources"), ("program", operators, "operator_sources"))}
        self.commands_refused = {}      # topic -> commands refused (an intruder on it)
        self.command_intruder = ""      # who published a command it may not (the source checks go on)
        self.commands_checked = 0.0     # monotonic time of the last check during a motion
        self.unnamed_commands = {}      # topic -> graph checks left to name a sender refused without a name
        self.next_command_check = 0     # the command topics are checked one at a time, in turn
        self.sources = [SourceGate("drives/state", values["state_source"], "state_source")]
        if strategy.uses_metrology:
            self.sources.append(SourceGate(strategy.metrology_topic, values["metrology_source"], "metrology_source"))
        self.sources_connected = False
        self.matched = {}               # input topic -> publishers matched to its subscription
        self.intruder = ""              # the intruders' node names, once the graph knows them
        self.sources_checked = 0.0      # monotonic time of the last check of the graph

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
        if not self.sources_connected:
            self.sources_connected = True            # the first state answered: its source is ours
            self.check_sources()
        status = plant_status(msg.frame_id)
        if status.stopped and not self.core.stopped:
            self.safe_stop_plant(status.cause)     # the drives' status word: the plant braked
        if not self.pairing.state_arrived(msg.stamp_ns, now):
            # a repeat: sim_hw republishes a state it has no answer for (step 0 until the
            # graph is connected; later a lost message); our answer was lost: again
            stamp, command = self.last_answer
            if stamp == msg.stamp_ns and command:
                self.ports.resend_command(command)
                self.commands_resent += 1
            return
        start = time.perf_counter()
        prepared = self.prepare(msg, status)
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
        if not self.commanded("trajectory", Action.TRAJECTORY, buf):
            return
        try:
            data = decode_multidof_trajectory(buf)
            ref = reference_from_trajectory(data, self.core.model.task_space)
            check_consistent(ref)      # a bogus one refused for what it is, before it trips anything
        except ValueError as exc:      # recorded too: the replay pairs every trajectory with its event
            self.report([apply_action(self.core, Action.TRAJECTORY, exc)])
            return
        ref.stamp_ns = data.stamp_ns   # its verdict names it (the planner's plan_chain)
        self.operator(Action.TRAJECTORY, ref)

    def on_command(self, topic: str, action: Action, buf: bytes) -> None:
        """An operator's command from ``topic`` (settings, feed override: a String, its
        credential's line then its body): taken if its credential and its topic's
        publishers are the allowed ones (module doc)."""
        if not self.commanded(topic, action, buf):
            return
        try:
            body = split_text(decode_string(buf, topic))[1]
            payload = body if action != Action.FEED_OVERRIDE else _number(topic, body)
        except ValueError as exc:
            payload = exc                      # refused with its message (operator_actions.apply_action)
        self.operator(action, payload)

    def commanded(self, topic: str, action: Action | None, buf: bytes = b"") -> bool:
        """Whether a command on ``topic`` may be taken (sources.CommandGuard: every
        publisher of the topic allowed, then the message's credential, a key holder
        the topic allows). Else it is refused (recorded, counted; ``action`` None: no
        event) and, during a motion, the machine stops."""
        guard = self.commands[topic]
        found = guard.refused(lambda: self.ports.topic_senders(topic), buf)
        if found is None:
            return True
        if action is not None:
            self.commands_refused[topic] = self.commands_refused.get(topic, 0) + 1
            event = {"kind": action.value, "ok": False, "message": f"refused: {found.reason}",
                     "intruder": found.sender, "after_ns": self.last_answer[0]}
            # a trajectory's stamp, the planner's own refused while a rogue publishes: its
            # plan chain matches verdicts by it (believed only with a valid credential)
            if guard.stamped and len(buf) >= 12 and not found.by_credential and guard.authentic(buf):
                event["stamp_ns"] = stamp_ns_of(buf)
            self.report([event])
        if found.sender.startswith("("):          # no name in the message: the graph may give it later
            self.unnamed_commands.setdefault(topic, NAMING_CHECKS)
        if not self.command_intruder:
            self.command_intruder = found.sender
            self.ports.log_error(f"{topic}: {found.reason}")
        if self.active and not self.core.stopped and self.core.mode == "tracking":
            self.safe_stop(found.reason, TripCause.INTRUDER)
        return False

    def check_commands(self) -> None:
        """During a motion: a node publishing a command topic it may not stops the
        machine (it commands while the machine moves). One topic per call, in turn
        (a graph query each; called every COMMAND_CHECK_S)."""
        self.commands_checked = time.monotonic()
        gates = [topic for topic, guard in self.commands.items() if guard.names.allowed]
        if gates:
            topic = gates[self.next_command_check % len(gates)]
            self.next_command_check += 1
            self.commanded(topic, None)

    def name_command_intruder(self) -> None:
        """A command refused before the graph knew its sender (no credential, no name
        yet): ask the graph again, one topic a call, NAMING_CHECKS times at most (a
        process under an allowed name is never named)."""
        self.commands_checked = time.monotonic()
        topic = next(iter(self.unnamed_commands))
        found = self.commands[topic].refused(lambda: self.ports.topic_senders(topic))
        self.unnamed_commands[topic] -= 1
        if found is not None or not self.unnamed_commands[topic]:
            del self.unnamed_commands[topic]
        if found is not None and self.command_intruder.startswith("("):
            self.command_intruder = found.sender
            self.ports.log_error(f"the refused command's sender: {found.reason}")

    def operator(self, action: Action, payload) -> None:
        """A trajectory, feed override or settings change (operator_actions.py): applied at once
        before the first cycle, else right after the next answer (between two cycles)."""
        self.report(self.inbox.add(self.core, action, payload))

    def report(self, events: list) -> None:
        """Each applied or refused action: recorded on controller/events and logged."""
        for event in events:
            self.ports.publish_event(event_json(event))
            if event["ok"]:
                self.trajectory_accepted |= event["kind"] == Action.TRAJECTORY.value
                self.ports.log_info(event_summary(event))
            else:
                self.ports.log_error(event["message"])
                self.publish_status(extra=event_summary(event))

    def on_start(self, buf: bytes) -> None:
        """The orchestrator's start (a String ``start`` after its credential's line)."""
        if self.commanded("run/start", None, buf):
            try:
                started = split_text(decode_string(buf, "run/start"))[1] == "start"
            except ValueError:
                started = False
            self.start_received = self.start_received or started

    def on_estop(self, active: bool) -> None:
        """Stop at once, and record after which answered state (controller/events): the
        replay stops the controller at the same point, whatever order the recorder got
        the estop and the commands in."""
        if active and not self.core.stopped:
            self.report([apply_action(self.core, Action.ESTOP, None, after_ns=self.last_answer[0])])
            self.safe_stop("estop", TripCause.ESTOP)

    def on_matched(self, topic: str, count: int) -> None:
        """A publisher matched an input's subscription (before its first message)."""
        self.matched[topic] = count
        if self.sources_connected and count > 1 and not self.intruder:
            self.check_sources()

    def check_sources(self) -> None:
        """Ask the graph who publishes the inputs (a source not known yet: the one
        publisher there is). An intruder stops the machine at once, named, or counted
        until the graph knows its name (then named in the log and the summary)."""
        self.sources_checked = time.monotonic()
        for gate in self.sources:
            publishers = self.ports.input_publishers(gate.topic)
            matched = self.matched.get(gate.topic, 1)
            found = gate.check(publishers, matched) if gate.source else gate.connect(publishers, matched)
            if found is None:
                continue
            self.intruder = found.sender          # named: the checks end
            if self.active and not self.core.stopped:
                self.safe_stop(found.reason, TripCause.INTRUDER)
            elif found.sender:
                self.ports.log_error(found.reason)
            return

    def on_watchdog(self) -> None:
        if self.sources_connected and not self.intruder and \
                time.monotonic() - self.sources_checked >= SOURCE_CHECK_S:
            self.check_sources()
        if self.active and not self.core.stopped and self.core.mode == "tracking" and \
                time.monotonic() - self.commands_checked >= COMMAND_CHECK_S:
            self.check_commands()
        elif self.unnamed_commands and time.monotonic() - self.commands_checked >= COMMAND_CHECK_S:
            self.name_command_intruder()
        if not self.active or self.core.stopped or self.run_ended:
            return
        fault = self.pairing.silence_fault(time.monotonic(), self.values["state_timeout_s"],
                                           self.values["metrology_timeout_s"])
        if fault:
            self.safe_stop(fault, TripCause.WATCHDOG)

    # ----------------------------------------------------------------- output
    def prepare(self, msg, status: PlantStatus) -> bool:
        """First half of the cycle on a drive state (pkm_common.cdr.JointStateData) and
        the plant's status on it; False when the controller is stopped (the answer is
        zero forces)."""
        core = self.core
        self.was_stopped = core.stopped
        try:
            msg = in_order(msg, self.names, "drives/state")
        except ValueError as exc:
            core.trip(str(exc), TripCause.INPUT_REFUSED)
        return core.prepare(msg.stamp_ns, msg.position, msg.velocity, msg.effort,
                            held=status.held_ns)

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
        self.ports.publish_command(command)
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
        self.ports.after_cycle()

    def publish_reference(self, stamp_ns: int) -> None:
        if not self.publishes_reference:
            return
        position, orientation = machine_pose_components(self.core.space, self.core.record.reference)
        self.ports.publish_reference_bytes(self.reference_encoder.encode(stamp_ns, position, orientation))

    def publish_status(self, extra: str = "") -> None:
        if not self.publishes_status:
            return
        level, message, values = self.core.status()
        if extra:
            level, message = max(level, 1), f"{message}; {extra}"
        self.ports.publish_status(self.core.last_stamp_ns or 0, level, message, values)

    def safe_stop_plant(self, cause: TripCause) -> None:
        """The plant stopped on its own (its status word in drives/state): the
        controller stops with the plant's cause, not as a drive failure."""
        self.core.plant_stopped(cause)
        self.safe_stop(self.core.stop_reason, self.core.stop_cause)

    def safe_stop(self, reason: str, cause: TripCause) -> None:
        """Zero forces, brakes requested (estop latched), reported, and recorded after the
        last answered state (controller/events: the replay stops there too)."""
        self.report([apply_action(self.core, Action.SAFE_STOP, {"reason": reason, "cause": cause},
                                  after_ns=self.last_answer[0])])
        self.ports.log_error(f"safe stop: {self.core.stop_reason}")
        self.ports.publish_estop()
        self.publish_status()

    def summary(self) -> dict:
        """The run's summary file (configuration.run_summary) and the answers sent again."""
        return {**run_summary(self.core, self.compute_s, self.response_s, self.answers_published),
                "commands_resent": self.commands_resent, "intruder": self.intruder or self.command_intruder,
                "commands_refused": dict(self.commands_refused)}


def _number(topic: str, text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{topic}: expected a number, got {text[:40]!r}") from None
