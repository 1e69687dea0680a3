"""``sim_hw_node``: the simulated machine as a ROS 2 node (thin shell over plant.Plant).

Timing (DESIGN.md): in ``lockstep`` (default) the node publishes the state of step k
(``/clock``, ``drives/state``, ``platform/true_pose``, all stamped t_k), waits for the
``drives/command`` stamped t_k, then integrates to k+1 and publishes again. Until the
first command arrives the state is re-published at 10 Hz (discovery); after it, no
command within ``command_timeout_s`` (wall clock, not counting this process's own
stalls: pkm_common.watchdog) is a fault: brakes on, reported, and the node keeps
stepping on the commands that do come (ignored while stopped).
In ``realtime`` a wall timer publishes a step every dt, applying the latest command
(zero-order hold), from the first command on (before it, the initial state is held and
re-published as in lockstep). The answer to the state last published is applied when
it arrives (the plant integrates then, so that the tick only publishes: the step's
~0.1 ms is off the deadline's path; the same numbers as stepping at the tick); without
one, the tick steps on the command held. A step whose command was not for the
previous state counts as a deadline miss (until the plant stops): its state says ``setpoint_held:<stamp>`` in the status word
(the forces it reports answer the command of that stamp), and the drives' sync error counter
(sync_monitor, ``sync_error_limit``) brakes the plant when the misses come too often
(cause ``deadline_missed``).

A command of the wrong length, with unknown names or NaN, stamped ahead of the plant,
or from any node but the controller (pkm_sim_hw.authority) is refused: the machine is
stopped safely, with an ERROR diagnostic naming the cause (and the intruder); so is
``estop`` (latched) and an external load over its bound. Every refusal is published on
``drives/refused`` (pkm_sim_hw.refusals: a DiagnosticArray, so the bag shows it,
rate-limited) and logged at most once a second. Parameters: pkm_sim_hw.parameters.
``drives/state`` carries the plant's status in its ``header.frame_id``, in band like a
drive's status word: empty while running, ``safe_stop:<cause>`` once braked.
"""

from __future__ import annotations

import json
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from visualization_msgs.msg import MarkerArray

from pkm_common.causes import TripCause
from pkm_common.node_tap import NodeTap
from pkm_common.cdr import JointStateDecoder
from pkm_common.conversions import diagnostic_array, diagnostic_status, line_list_markers, ns_to_stamp, publisher_names
from pkm_common.params import declare_bool
from pkm_common.qos import CLOCK_PUBLISHER_QOS, LATCHED_QOS, STREAM_PUBLISHER_QOS, STREAM_QOS
from pkm_common.runner import main_exit, run_node
from pkm_common.timing import Cadence
from pkm_common.watchdog import SilenceWatchdog
from pkm_sim_hw.authority import APPLY, STALE, Refusal
from pkm_sim_hw.parameters import declare_settings
from pkm_sim_hw.plant import command_efforts, leg_segments
from pkm_sim_hw.refusals import RefusalReport
from pkm_sim_hw.run_record import RunRecord
from pkm_sim_hw.step_streams import StepStreams
from pkm_sim_hw.sync_monitor import SetpointHold

REPEAT_AFTER_S = 0.1         # lockstep: the state is published again when no command came for this long


class SimHwNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("sim_hw", context=context, **kwargs)
        settings = declare_settings(self)
        self.config, self.plant, self.gate = settings.machine, settings.plant, settings.gate
        self.lockstep, self.timeout_s = settings.lockstep, settings.command_timeout_s
        self.publish_markers, self.duration_s = settings.publish_markers, settings.duration_s
        self.duration_steps, self.summary_path = settings.duration_steps, settings.summary_path
        self.shutdown_on_finish = settings.shutdown_on_finish
        n, dt_s = self.plant.n, self.plant.params.dt_s
        self.run = RunRecord(self.config.name, self.lockstep)     # counters, intruder, steps: the summary's
        self.counts = self.run.counts
        self.dt_ns = round(dt_s * 1e9)
        self.command_matches = 1                # publishers matched to drives/command (the matched event)
        self.started = False
        # the command watchdog does not count this process's own stalls (another node's
        # callback in a shared executor): 3 periods of its 0.1 s timer
        self.command_watchdog = SilenceWatchdog(own_stall_s=0.3)
        self.hold = SetpointHold(n, settings.sync_error_limit)    # realtime: the drives' zero-order hold
        self.command_decoder = JointStateDecoder("drives/command")
        self.tap = NodeTap(self, declare_bool(self, "tap", False, "copy the per-step streams to a recorder "
                                              "in batches (pkm_common.tap) instead of its subscribing to them"))
        self.pub_clock = self.tap.wrap(self.create_publisher(Clock, "/clock", CLOCK_PUBLISHER_QOS), Clock)
        self.pub_state = self.tap.wrap(self.create_publisher(JointState, "drives/state", STREAM_PUBLISHER_QOS),
                                       JointState)
        self.pub_pose = self.tap.wrap(self.create_publisher(PoseStamped, "platform/true_pose",
                                                            STREAM_PUBLISHER_QOS), PoseStamped)
        self.streams = StepStreams(self.plant, self.config.model.task_space, self.pub_pose, self.pub_state,
                                   self.pub_clock)
        self.pub_diag = self.create_publisher(DiagnosticArray, "diagnostics", STREAM_QOS)
        self.refusals = RefusalReport(self, self.counts)
        self.pub_markers = self.create_publisher(MarkerArray, "markers", LATCHED_QOS)
        self.command_sub = self.create_subscription(
            JointState, "drives/command", self.on_command, STREAM_QOS, raw=True,
            event_callbacks=SubscriptionEventCallbacks(matched=self.on_command_matched))
        self.create_subscription(WrenchStamped, "load", self.on_load, STREAM_QOS)
        self.create_subscription(Bool, "estop", self.on_estop, LATCHED_QOS)
        self.create_timer(0.1, self.on_watchdog)
        # markers and diagnostics right after a step's publish (pkm_common.timing.Cadence:
        # off the deadline's path), on their timers only when no step runs
        self.cadences = ((Cadence(1.0), self.publish_diagnostics),) + \
            (((Cadence(0.1), self.publish_marker_array),) if self.publish_markers else ())
        for cadence, work in self.cadences:
            self.create_timer(cadence.period_s, lambda c=cadence, w=work: c.on_timer() and w())
        if not self.lockstep:
            self.create_timer(dt_s, self.on_realtime_tick)
        self.publish_state()

    @property
    def finished(self) -> bool:
        """The run's last step is done (an in-process run waits for it)."""
        return self.run.finished

    # ------------------------------------------------------------- publishing
    def now_ns(self) -> int:
        return self.plant.k * self.dt_ns

    def publish_state(self) -> None:
        """Clock, drives/state and platform/true_pose of the current step."""
        ns = self.now_ns()
        self.run.published(ns)
        self.streams.publish(ns)

    def publish_diagnostics(self) -> None:
        level, message, values = self.run.diagnostics(self.plant, self.plant.output())
        self.pub_diag.publish(diagnostic_array(ns_to_stamp(self.now_ns()),
                                               [diagnostic_status("sim_hw", level, message, values)]))

    def publish_marker_array(self) -> None:
        self.pub_markers.publish(line_list_markers(leg_segments(self.plant.machine, self.plant.x), self.now_ns()))

    # ------------------------------------------------------------------ inputs
    def _refuse(self, refusal: Refusal | str, topic: str = "drives/command") -> None:
        """Not applied: counted, recorded on drives/refused, logged (at most once a
        second) and, for most refusals, the machine stopped safely with its cause."""
        if isinstance(refusal, str):
            refusal = Refusal(refusal, TripCause.INPUT_REFUSED)
        text = self.run.refused(refusal, topic)
        if refusal.stop:
            self.plant.safe_stop(text, refusal.cause)
        self.refusals.report(refusal, topic, text, self.plant.k, self.now_ns())
        self.publish_diagnostics()

    def command_publishers(self) -> list[str]:
        """Full names of the nodes publishing drives/command, one per publisher (the
        graph's view; a node not known yet is left out: the matched count and the
        later ticks see it)."""
        return publisher_names(self.get_publishers_info_by_topic(self.command_sub.topic_name))

    def on_command_matched(self, status) -> None:
        """A publisher matched drives/command (before its first message is delivered)."""
        self.command_matches = status.current_count
        if self.started and not self.run.intruder and not self.run.finished and status.current_count > 1:
            self._refuse(self.gate.check_publishers(self.command_publishers()) or Refusal(
                f"{status.current_count} publishers on drives/command", TripCause.INTRUDER))

    def on_command(self, buf: bytes) -> None:
        if self.run.finished:
            return
        try:
            msg = self.command_decoder.decode(buf)
        except ValueError as exc:                  # malformed bytes from a raw publisher
            self._refuse(str(exc))
            return
        stamp = msg.stamp_ns
        self.hold.command_came()
        intruder = None if self.started else self.gate.connect(self.command_publishers(), self.command_matches)
        if intruder:                               # braked; lockstep goes on with the answers that come
            self._refuse(intruder)
        verdict = self.gate.check_stamp(stamp, self.run.last_published_ns)     # realtime: plant may be ahead
        if verdict == STALE:
            self.counts["stale_commands"] += 1    # an answer to an older state: not alive
            return
        if verdict != APPLY:                       # not an answer; in real time the last valid one holds
            self._refuse(verdict)
            return
        effort, why = command_efforts(msg, self.plant.names)
        if effort is None:
            self._refuse(why)
            effort = [0.0] * self.plant.n          # stopped anyway; lockstep goes on
        self.started = True
        now = time.monotonic()
        self.command_watchdog.feed(now)            # only a fresh command feeds the watchdog
        if self.run.first_command_wall is None:
            self.run.first_command_wall = now
        if not self.lockstep:
            if self.hold.latch(effort, stamp, self.run.last_published_ns):
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
            self.get_logger().error(self.plant.stop_reason)
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
        self.tap.after_cycle()
        for cadence, work in self.cadences:
            if cadence.in_cycle():
                work()
        if self.duration_steps and self.plant.k >= self.duration_steps:
            self.finish()

    def summary(self) -> dict:
        return self.run.summary(self.plant, time.monotonic())

    def write_summary(self) -> None:
        if self.summary_path:
            with open(self.summary_path, "w", encoding="utf-8") as fh:
                json.dump(self.summary(), fh, indent=2)

    def finish(self) -> None:
        """The run is complete: summary, then shut the context down (clean exit 0)."""
        self.run.finished = True
        self.publish_diagnostics()
        self.get_logger().info(f"run complete: {json.dumps(self.summary())}")
        self.write_summary()
        if self.shutdown_on_finish:                # the last steps, while the context is up
            self.tap.close()
            rclpy.try_shutdown(context=self.context)
        else:                                      # in one process: the run's executor drains it
            self.tap.flush()

    def destroy_node(self):
        if not self.run.finished and hasattr(self, "run"):
            self.write_summary()                   # interrupted: what was done so far
            self.tap.close()
        return super().destroy_node()

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
            intruder = self.gate.check_publishers(self.command_publishers())
            if intruder:
                self._refuse(intruder)
        if self.started and silence_s > self.timeout_s and not self.plant.stopped:   # lockstep and realtime
            self.counts["timeouts"] += 1
            self.plant.safe_stop(f"no drives/command within {self.timeout_s} s", TripCause.WATCHDOG)
            self.get_logger().error(self.plant.stop_reason)
            self.publish_diagnostics()
            self.publish_state()

    def on_load(self, msg: WrenchStamped) -> None:
        f, m = msg.wrench.force, msg.wrench.torque
        try:
            self.plant.set_load(self.plant.load_components((f.x, f.y, f.z), (m.x, m.y, m.z)))
        except ValueError as exc:                  # nothing applied; the experiment cannot go on
            self._refuse(Refusal(str(exc), TripCause.LOAD_REFUSED), topic="load")

    def on_estop(self, msg: Bool) -> None:
        if msg.data:
            self.plant.safe_stop("estop", TripCause.ESTOP)
            self.publish_diagnostics()


def main(args=None):
    main_exit(run_node(SimHwNode, args=args, name="sim_hw", executor="events"))


if __name__ == "__main__":
    main()
