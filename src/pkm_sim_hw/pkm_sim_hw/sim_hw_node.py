"""``sim_hw_node``: the simulated machine as a ROS 2 node (thin shell over sim_loop.SimLoop,
which steps a plant.Plant).

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

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from pkm_common import topics
from pkm_common.conversions import diagnostic_bytes, graph_senders, line_list_markers, publisher_names
from pkm_common.endpoints import publisher, subscription
from pkm_common.params import declare_bool
from pkm_common.runner import main_exit, run_node
from pkm_recording.node_tap import NodeTap
from pkm_sim_hw.parameters import declare_settings
from pkm_sim_hw.refusals import RefusalReport
from pkm_sim_hw.sim_loop import SimLoop
from pkm_sim_hw.step_streams import StepStreams


class SimHwNode(Node):
    """The middleware around a ``sim_loop.SimLoop`` (its ``ports``: the publishers,
    the graph, the logger). A subclass steps other hardware in the same loop
    (pkm_drives.drives_node): its ``make_settings`` gives it, ``simulated`` False
    (no ground truth, no simulated load, no markers)."""

    simulated = True

    def __init__(self, context=None, node_name: str = "sim_hw", **kwargs):
        super().__init__(node_name, context=context, **kwargs)
        settings = self.make_settings()
        self.config, self.plant = settings.machine, settings.plant
        self.shutdown_on_finish = settings.shutdown_on_finish
        self.tap = NodeTap(self, declare_bool(self, "tap", False, "copy the per-step streams to a recorder "
                                              "in batches (pkm_recording.tap) instead of its subscribing to them"))
        self.pub_clock = self.tap.wrap(publisher(self, topics.CLOCK), Clock)
        self.pub_state = self.tap.wrap(publisher(self, topics.DRIVES_STATE), JointState)
        self.pub_pose = self.tap.wrap(publisher(self, topics.TRUE_POSE), PoseStamped) if self.simulated else None
        streams = StepStreams(self.plant, self.config.model.task_space, self.pub_pose, self.pub_state, self.pub_clock)
        self.loop = loop = SimLoop(settings, streams, self)
        self.run, self.counts = loop.run, loop.counts
        self.pub_diag = publisher(self, topics.DIAGNOSTICS)
        self.refusals = RefusalReport(self, self.counts)
        self.pub_markers = publisher(self, topics.MARKERS) if self.simulated else None
        self.command_sub = subscription(
            self, topics.DRIVES_COMMAND, loop.on_command, raw=True,
            event_callbacks=SubscriptionEventCallbacks(matched=lambda s: loop.on_command_matched(s.current_count)))
        if self.simulated:
            self.load_sub = subscription(self, topics.LOAD, loop.on_load_message, raw=True)
        subscription(self, topics.ESTOP, lambda m: loop.on_estop(bool(m.data)))
        self.create_timer(0.1, loop.on_watchdog)
        for cadence, work in loop.cadences:
            self.create_timer(cadence.period_s, lambda c=cadence, w=work: c.on_timer() and w())
        if not loop.lockstep:
            self.create_timer(self.plant.params.dt_s, loop.on_realtime_tick)
        loop.publish_state()

    def make_settings(self):
        """The loop's settings from the node's parameters (parameters.declare_settings)."""
        return declare_settings(self)

    @property
    def finished(self) -> bool:
        """The run's last step is done (an in-process run waits for it)."""
        return self.run.finished

    def now_ns(self) -> int:
        return self.loop.now_ns()

    def summary(self) -> dict:
        return self.loop.summary()

    # ------------------------------------------------- the loop's ports (sim_loop)
    def publish_diagnostics(self, stamp_ns: int, level: int, message: str, values: dict) -> None:
        self.pub_diag.publish(diagnostic_bytes(stamp_ns, self.get_name(), level, message, values))

    def publish_markers(self, segments, stamp_ns: int) -> None:
        self.pub_markers.publish(line_list_markers(segments, stamp_ns))

    def report_refusal(self, refusal, topic: str, text: str, plant_step: int, now_ns: int) -> None:
        self.refusals.report(refusal, topic, text, plant_step, now_ns)

    def load_senders(self) -> list[str]:
        return graph_senders(self, self.load_sub.topic_name)

    def command_publishers(self) -> list[str]:
        """Full names of the nodes publishing drives/command, one per publisher (the
        graph's view; a node not known yet is left out: the matched count and the
        later ticks see it)."""
        return publisher_names(self.get_publishers_info_by_topic(self.command_sub.topic_name))

    def after_cycle(self) -> None:
        self.tap.after_cycle()

    def run_finished(self) -> None:
        """Shut the context down (a clean exit 0), or, in one process, let the run's
        executor drain the last steps."""
        if self.shutdown_on_finish:                # the last steps, while the context is up
            self.tap.close()
            rclpy.try_shutdown(context=self.context)
        else:
            self.tap.flush()

    def log_info(self, text: str) -> None:
        self.get_logger().info(text)

    def log_error(self, text: str) -> None:
        self.get_logger().error(text)

    def destroy_node(self):
        if hasattr(self, "loop") and not self.run.finished:
            self.loop.write_summary()              # interrupted: what was done so far
            self.tap.close()
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(SimHwNode, args=args, name="sim_hw", executor="events"))


if __name__ == "__main__":
    main()
