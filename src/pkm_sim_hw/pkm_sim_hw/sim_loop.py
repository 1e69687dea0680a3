"""What sim_hw_node does with each message and tick, without rclpy: the lockstep and
realtime stepping, the command authority, the watchdog, the safe stops and the run's
end. It works on the messages' bytes (pkm_common.cdr) and hands what goes out to
``ports``, which the node implements with its publishers and its view of the graph
(the timing and the refusals are described in sim_hw_node's docstring).

``ports`` is a ``SimPorts`` (below): what the loop sends out and asks the graph.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from typing import Protocol

from pkm_common.causes import TripCause
from pkm_common.cdr import JointStateDecoder, decode_wrench_stamped
from pkm_common.credential import Verifier
from pkm_common.files import reserve_file, write_summary as write_summary_file
from pkm_common.sources import AllowedSenders, CommandGuard
from pkm_common.timing import Cadence
from pkm_common.watchdog import SilenceWatchdog
from pkm_kinematics.config import MachineConfig

from .authority import APPLY, STALE, CommandGate, Refusal
from .plant import Plant, command_efforts, leg_segments
from .run_record import RunRecord
from .step_streams import StepStreams
from .sync_monitor import SetpointHold

__all__ = ["REPEAT_AFTER_S", "SimHwSettings", "SimLoop", "SimPorts"]

NAMING_CHECKS = 20           # watchdog ticks (0.1 s) to name a load's sender refused before the graph knew it
REPEAT_AFTER_S = 0.1         # lockstep: the state is published again when no command came for this long


@dataclass
class SimHwSettings:
    """What the loop runs with (sim_hw_node: parameters.declare_settings from its ROS
    parameters; without ROS, made directly); ``plant`` is built and loaded with its
    schedule."""

    machine: MachineConfig
    plant: Plant
    lockstep: bool
    command_timeout_s: float
    sync_error_limit: int            # realtime: the drives' sync error counter limit (sync_monitor)
    gate: CommandGate
    publish_markers: bool
    duration_s: float
    duration_steps: int              # simulated time as a step count (plant.t accumulates dt)
    summary_path: str
    shutdown_on_finish: bool
    load_senders: AllowedSenders = AllowedSenders("load", ())    # who may send a load (empty: anyone)
    credentials: Verifier = Verifier(None)     # the run's key: a load carries its credential (none: not needed)
    homing: str = ""                 # what the machine's homing did before the run ("": none)


class SimPorts(Protocol):
    """What a SimLoop needs of its shell (sim_hw_node implements it)."""

    def publish_diagnostics(self, stamp_ns: int, level: int, message: str, values: dict) -> None:
        """diagnostics (sim_hw's status)."""

    def publish_markers(self, segments, stamp_ns: int) -> None:
        """markers (the legs, for a viewer)."""

    def report_refusal(self, refusal, topic: str, text: str, plant_step: int, now_ns: int) -> None:
        """drives/refused and the rate-limited log."""

    def command_publishers(self) -> list[str]:
        """The full names of the nodes publishing drives/command, as the graph knows them."""

    def load_senders(self) -> list[str]:
        """The same of ``load``."""

    def after_cycle(self) -> None:
        """The recording tap's flush point."""

    def run_finished(self) -> None:
        """The last step is done: end the process, or let the executor drain."""

    def log_info(self, text: str) -> None: ...

    def log_error(self, text: str) -> None: ...


class SimLoop:
    """The simulated machine of ``settings`` (parameters.declare_settings), publishing
    its steps on ``streams`` (step_streams.StepStreams)."""

    def __init__(self, settings: SimHwSettings, streams: StepStreams, ports: SimPorts):
        self.config, self.plant, self.gate = settings.machine, settings.plant, settings.gate
        self.load_senders = settings.load_senders
        self.load_guard = CommandGuard(settings.load_senders, settings.credentials)
        self.load_naming_checks = 0             # graph checks left to name a load's sender refused unnamed
        self.lockstep, self.timeout_s = settings.lockstep, settings.command_timeout_s
        self.duration_s, self.duration_steps = settings.duration_s, settings.duration_steps
        self.summary_path = settings.summary_path
        if self.summary_path:
            reserve_file(self.summary_path)       # a disk the bag fills cannot take the summary's place
        self.streams, self.ports = streams, ports
        self.run = RunRecord(self.config.name, self.lockstep, settings.homing)   # counters, intruder, steps
        self.counts = self.run.counts
        self.command_matches = 1                # publishers matched to drives/command (the matched event)
        self.started = False
        # the command watchdog does not count this process's own stalls (another node's
        # callback in a shared executor): 3 periods of its 0.1 s timer
        self.command_watchdog = SilenceWatchdog(own_stall_s=0.3)
        self.hold = SetpointHold(self.plant.n, settings.sync_error_limit)    # realtime: the drives' hold
        self.command_decoder = JointStateDecoder("drives/command")
        # markers and diagnostics right after a step's publish (pkm_common.timing.Cadence:
        # off the deadline's path), on their timers only when no step runs
        self.cadences = ((Cadence(1.0), self.publish_diagnostics),) + \
            (((Cadence(0.1), self.publish_marker_array),) if settings.publish_markers else ())

    # ------------------------------------------------------------- publishing
    def now_ns(self) -> int:
        return self.plant.k * self.plant.dt_ns

    def publish_state(self) -> None:
        """Clock, drives/state and platform/true_pose of the current step."""
        ns = self.now_ns()
        self.run.published(ns)
        self.streams.publish(ns)

    def publish_diagnostics(self) -> None:
        level, message, values = self.run.diagnostics(self.plant, self.plant.output())
        self.ports.publish_diagnostics(self.now_ns(), level, message, values)

    def publish_marker_array(self) -> None:
        self.ports.publish_markers(leg_segments(self.plant.machine, self.plant.x), self.now_ns())

    # ------------------------------------------------------------------ inputs
    def refuse(self, refusal: Refusal | str, topic: str = "drives/command") -> None:
        """Not applied: counted, recorded on drives/refused, logged (at most once a
        second) and, for most refusals, the machine stopped safely with its cause."""
        if isinstance(refusal, str):
            refusal = Refusal(refusal, TripCause.INPUT_REFUSED)
        text = self.run.refused(refusal, topic)
        if refusal.stop:
            self.plant.safe_stop(text, refusal.cause)
        self.ports.report_refusal(refusal, topic, text, self.plant.k, self.now_ns())
        self.publish_diagnostics()

    def on_command_matched(self, current_count: int) -> None:
        """A publisher matched drives/command (before its first message is delivered)."""
        self.command_matches = current_count
        if self.started and not self.run.intruder and not self.run.finished and current_count > 1:
            intruder = self.gate.check_publishers(self.ports.command_publishers(), current_count)
            if intruder:
                self.refuse(intruder)

    def on_command(self, buf: bytes) -> None:
        if self.run.finished:
            return
        try:
            msg = self.command_decoder.decode(buf)
        except ValueError as exc:                  # malformed bytes from a raw publisher
            self.refuse(str(exc))
            return
        stamp = msg.stamp_ns
        self.hold.command_came()
        intruder = None if self.started else self.gate.connect(self.ports.command_publishers(),
                                                               self.command_matches)
        if intruder:                               # braked; lockstep goes on with the answers that come
            self.refuse(intruder)
        verdict = self.gate.check_stamp(stamp, self.run.last_published_ns)     # realtime: plant may be ahead
        if verdict == STALE:
            self.counts["stale_commands"] += 1    # an answer to an older state: not alive
            return
        if verdict != APPLY:                       # not an answer; in real time the last valid one holds
            self.refuse(verdict)
            return
        if not self.plant.homed:                   # its positions are not the machine's yet
            self.refuse(Refusal("not homed: drive commands are refused until the machine is homed "
                                "(drives.homing)", TripCause.INPUT_REFUSED, stamp, stop=False))
            return
        effort, why = command_efforts(msg, self.plant.names)
        if effort is None:
            self.refuse(why)
            effort = [0.0] * self.plant.n          # stopped anyway; lockstep goes on
        self.started = True
        now = time.monotonic()
        self.command_watchdog.feed(now)            # only a fresh command feeds the watchdog
        if self.run.first_command_wall is None:
            self.run.first_command_wall = now
            # when the loop began (start-up under load can take seconds after the graph connected)
            self.ports.log_info(f"loop started: the first command, at step {self.plant.k}")
        if not self.lockstep:
            if self.hold.latch(effort, stamp, self.run.last_published_ns):
                self.side_work()                   # of the step published (its stamp), before the next is made
                self.plant.step(effort)            # the next tick's step, made now; the tick publishes it
            return
        self.advance(effort)

    def on_realtime_tick(self) -> None:
        if not self.started or self.run.finished:
            return                                 # held until the controller's first command
        effort, held, tripped = self.hold.tick(self.run.last_published_ns)
        # a miss is a held setpoint of a running plant (not a stopped one's)
        self.counts["deadline_misses"] += held is not None and not self.plant.stopped
        if tripped and not self.plant.stopped:
            self.plant.safe_stop(self.hold.sync.tripped, self.hold.sync.cause)
            self.ports.log_error(self.plant.stop_reason)
            self.publish_diagnostics()
        if effort is None:                         # stepped on the fresh answer at its arrival
            self.publish_step()
        else:
            self.advance(effort, held)

    def advance(self, effort, held_stamp_ns: int | None = None) -> None:
        """One step on ``effort``, published."""
        self.plant.step(effort)
        self.publish_step(held_stamp_ns)

    def publish_step(self, held_stamp_ns: int | None = None) -> None:
        """The step just made; ``held_stamp_ns``: its command was the one of that stamp
        again (the answer to the last state missed the tick), said in the status word,
        where the drive supervision finds the command to compare."""
        self.streams.hold(held_stamp_ns)
        self.publish_state()
        if self.lockstep:
            self.side_work()
        if self.duration_steps and self.plant.k >= self.duration_steps:
            self.finish()

    def side_work(self) -> None:
        """The recorder's batch, the markers and the diagnostics when due: in lockstep
        right after a step's publication (the plant then waits for its answer), in real
        time once the answer to it is in (before the next step is made, its tick not yet
        due). In a composed loop (one thread: pkm_bringup.composed_loop) the work right
        after the publication sat between the state and the controller, on the
        deadline's path. Their timers do it when no cycle runs (Cadence.on_timer)."""
        self.ports.after_cycle()
        for cadence, work in self.cadences:
            if cadence.in_cycle():
                work()

    def summary(self) -> dict:
        return self.run.summary(self.plant, time.monotonic())

    def write_summary(self) -> None:
        if self.summary_path:
            write_summary_file(self.summary_path, self.summary(), self.ports.log_error)

    def finish(self) -> None:
        """The run is complete: diagnostics, summary, then the node ends the run."""
        self.run.finished = True
        self.publish_diagnostics()
        self.ports.log_info(f"run complete: {json.dumps(self.summary())}")
        self.write_summary()
        self.ports.run_finished()

    def on_watchdog(self) -> None:
        if self.run.finished:
            return
        silence_s = self.command_watchdog.silence_s(time.monotonic())
        if not self.started:
            self.publish_state()                   # until the controller has discovered us
        elif self.lockstep and silence_s is not None and silence_s >= REPEAT_AFTER_S:
            # no answer yet: a state, a reading or a command was lost on the way (a
            # reliable sample lost in transport waits for DDS's next heartbeat, seconds);
            # the repeat is answered again (the controller re-sends its command)
            self.counts["state_repeats"] += 1
            self.publish_state()
        if self.started and not self.run.intruder_named:      # also names one only counted so far
            intruder = self.gate.check_publishers(self.ports.command_publishers())
            if intruder:
                self.refuse(intruder)
        if self.load_naming_checks and not self.run.intruder_named:   # a load refused before its sender had a name
            self.load_naming_checks -= 1
            found = self.load_guard.refused(self.ports.load_senders)
            if found is not None:
                self.run.intruder, self.load_naming_checks = found.sender, 0
                self.ports.log_error(f"the refused load's sender: {found.reason}")
        if self.started and silence_s > self.timeout_s and not self.plant.stopped:   # lockstep and realtime
            self.counts["timeouts"] += 1
            self.plant.safe_stop(f"no drives/command within {self.timeout_s} s", TripCause.WATCHDOG)
            self.ports.log_error(self.plant.stop_reason)
            self.publish_diagnostics()
            self.publish_state()

    def on_load_message(self, buf: bytes) -> None:
        """A ``load`` message (WrenchStamped bytes): its senders and its credential
        checked (pkm_common.sources.CommandGuard), then on_load's bounds."""
        found = self.load_guard.refused(self.ports.load_senders, buf)
        if found is not None:
            # a message that names no sender: the graph may name its node later (on_watchdog)
            unnamed = found.sender.startswith("(")
            if unnamed:
                self.load_naming_checks = NAMING_CHECKS
            self.refuse(Refusal(found.reason, TripCause.INTRUDER, sender="" if unnamed else found.sender),
                        topic="load")
            return
        try:
            force, moment = decode_wrench_stamped(buf, "load")
        except ValueError as exc:
            self.refuse(Refusal(str(exc), TripCause.INPUT_REFUSED), topic="load")
            return
        self.apply_load(force, moment)

    def load_sender_refused(self) -> bool:
        """A node the run does not name (``load_sources``) publishes a load: refused,
        the machine stopped."""
        senders = self.load_senders
        found = senders.check(self.ports.load_senders()) if senders.allowed else None
        if found is not None:
            self.refuse(Refusal(found.reason, TripCause.INTRUDER, sender=found.sender), topic="load")
        return found is not None

    def on_load(self, force, moment) -> None:
        """An external load (a simulation input): from the nodes the run names
        (``load_sources``), within its bounds; else refused and the machine stopped."""
        if not self.load_sender_refused():
            self.apply_load(force, moment)

    def apply_load(self, force, moment) -> None:
        try:
            self.plant.set_load(self.plant.load_components(force, moment))
        except ValueError as exc:                  # nothing applied; the experiment cannot go on
            self.refuse(Refusal(str(exc), TripCause.LOAD_REFUSED), topic="load")

    def on_estop(self, active: bool) -> None:
        if active:
            self.plant.safe_stop("estop", TripCause.ESTOP)
            self.publish_diagnostics()
