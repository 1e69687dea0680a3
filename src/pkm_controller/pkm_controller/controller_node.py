"""``controller_node``: the redundant-actuation controller as a lifecycle node (thin
shell over controller.ControllerCore).

configure: read and validate the parameters (config/controller/*.yaml); a bad one
fails the transition with its name and allowed range. activate: answer every
``drives/state`` (and, for the metrology strategies, the ``metrology/struts`` or
``metrology/pose`` of the same stamp) with ``drives/command`` stamped like the state
(lockstep). ``trajectory`` (latched) starts at the next state; with
``wait_for_trajectory`` / ``wait_for_start`` no state is answered before the
trajectory / a latched ``run/start`` (an orchestrator's start signal: a String ``start``);
with ``credential_file`` every command carries the run's credential (node_loop); ``estop`` and every
trip of the supervisor put the controller in its safe state (zero forces) and latch
``estop`` so the drives brake. A wall-clock watchdog trips when ``drives/state`` or
the metrology stops for ``state_timeout_s`` / ``metrology_timeout_s``, from the
first state answered, until the state of ``end_time_s`` (the run's last step, after
which the plant is silent by design; 0: no known end). (DDS deadline
QoS would need the publisher to offer a deadline too; sim_hw in lockstep publishes
only when answered, so a timer on the controller's side is the same test.)
Each input has one source (``state_source``, ``metrology_source``: full node names;
empty: the one publisher at the first state): another publisher stops the machine
(cause intruder, node_loop). With ``autostart`` (default) the node configures and
activates itself.
"""

from __future__ import annotations

from dataclasses import fields

from geometry_msgs.msg import PoseStamped
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.lifecycle import TransitionCallbackReturn
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String

from pkm_common import topics
from pkm_common.causes import TripCause
from pkm_common.conversions import diagnostic_bytes, graph_senders, publisher_names
from pkm_common.credential import Verifier
from pkm_common.endpoints import publisher, subscription
from pkm_common.files import reserve_file, write_summary
from pkm_common.params import declare_bool, declare_like
from pkm_common.runner import main_exit, run_node
from pkm_recording.node_tap import NodeTap
from pkm_controller.configuration import NODE_PARAMETERS, core_from_parameters, warm_up
from pkm_controller.config import ControllerConfig
from pkm_controller.node_loop import ControllerLoop
from pkm_controller.operator_actions import Action


class ControllerNode(LifecycleNode):
    """The middleware around a ``node_loop.ControllerLoop`` (its ``ports``: the
    publishers and the logger)."""

    def __init__(self, context=None, **kwargs):
        super().__init__("controller", context=context, **kwargs)
        self.loop = None               # the configured controller (node_loop.ControllerLoop)
        self.entities = []
        self.inputs = {}               # input topic -> its subscription (publishers())
        self.configure_error = ""
        self.tap = NodeTap(self, declare_bool(self, "tap", False, "copy drives/command and controller/reference "
                                              "to a recorder in batches (pkm_recording.tap)"))
        if declare_bool(self, "autostart", True, "configure and activate at start"):
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise ValueError(self.configure_error)
            self.trigger_activate()

    @property
    def core(self):
        """The controller core (None before configure and after cleanup)."""
        return None if self.loop is None else self.loop.core

    # ------------------------------------------------------------- lifecycle
    def _read_parameters(self) -> tuple[dict, ControllerConfig]:
        values = {name: declare_like(self, name, default) for name, default in NODE_PARAMETERS.items()}
        config = {f.name: declare_like(self, f.name, f.default) for f in fields(ControllerConfig)}
        return values, ControllerConfig(**config)

    def on_configure(self, state) -> TransitionCallbackReturn:
        try:
            values, config = self._read_parameters()
            core = core_from_parameters(values["machine"], config)
            credentials = Verifier.from_file(values["credential_file"])
            warm_up(core)                   # the kernels loaded now, not in the first cycles
        except ValueError as exc:
            self.configure_error = str(exc)
            self.get_logger().error(f"configure refused: {exc}")
            return TransitionCallbackReturn.FAILURE
        self.values = values
        if values["summary_path"]:
            reserve_file(values["summary_path"])    # a disk the bag fills cannot take the summary's place
        loop = self.loop = ControllerLoop(core, values, self, credentials)
        strategy = core.strategy
        self.pub_command = publisher(self, topics.DRIVES_COMMAND)
        self.pub_reference = publisher(self, topics.CONTROLLER_REFERENCE)
        self.publish_command = self.tap.wrap(self.pub_command, JointState).publish
        self.publish_reference_bytes = self.tap.wrap(self.pub_reference, PoseStamped).publish
        self.pub_status = publisher(self, topics.CONTROLLER_STATUS)
        self.pub_estop = publisher(self, topics.ESTOP)
        self.pub_events = publisher(self, topics.CONTROLLER_EVENTS)
        self.entities = [self.pub_command, self.pub_reference, self.pub_status, self.pub_estop, self.pub_events,
                         self._command(topics.FEED_OVERRIDE, lambda b: loop.on_command(
                             topics.FEED_OVERRIDE, Action.FEED_OVERRIDE, b)),
                         self._command(topics.SETTINGS, lambda b: loop.on_command(
                             topics.SETTINGS, Action.SETTINGS, b)),
                         self._input(topics.DRIVES_STATE, loop.on_state),
                         self._command(topics.TRAJECTORY, loop.on_trajectory),
                         subscription(self, topics.ESTOP, lambda m: loop.on_estop(bool(m.data))),
                         self._command(topics.RUN_START, loop.on_start),
                         self.create_timer(0.01, loop.on_watchdog)]
        if strategy.uses_metrology:
            self.entities.append(self._input(strategy.metrology_topic, loop.on_metrology))
        self.get_logger().info(f"configured: {values['machine']}, {config.strategy}, {config.distribution}")
        return TransitionCallbackReturn.SUCCESS

    def _input(self, topic: str, callback):
        """A per-step input (raw bytes) whose publishers are watched (node_loop: one source)."""
        self.inputs[topic] = subscription(
            self, topic, callback, raw=True,
            event_callbacks=SubscriptionEventCallbacks(matched=lambda s, loop=self.loop: loop.on_matched(
                topic, s.current_count)))
        return self.inputs[topic]

    def _command(self, topic: str, callback):
        """A command input (raw bytes: its credential covers them), whose publishers are
        asked for at each message (node_loop)."""
        self.inputs[topic] = subscription(self, topic, callback, raw=True)
        return self.inputs[topic]

    def on_activate(self, state) -> TransitionCallbackReturn:
        self.loop.active = True
        self.loop.pairing.reset_watchdog()
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        self.loop.active = False
        self.loop.safe_stop("deactivated", TripCause.DEACTIVATED)
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        self._destroy_entities()
        self.loop = None
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
        self.inputs = {}

    # ------------------------------------------------ the loop's ports (node_loop)
    def input_publishers(self, topic: str) -> list[str]:
        return publisher_names(self.get_publishers_info_by_topic(self.inputs[topic].topic_name))

    def topic_senders(self, topic: str) -> list[str]:
        """The node names publishing ``topic``: an input of this node, or
        another's (goal, program); a graph that cannot be asked refuses (fails closed)."""
        return graph_senders(self, self.inputs[topic].topic_name if topic in self.inputs
                             else self.resolve_topic_name(topic))

    def resend_command(self, command: bytes) -> None:
        self.pub_command.publish(command)        # not tapped: the bag holds one per stamp

    def publish_status(self, stamp_ns: int, level: int, message: str, values: dict) -> None:
        self.pub_status.publish(diagnostic_bytes(stamp_ns, "controller", level, message, values))

    def publish_event(self, text: str) -> None:
        self.pub_events.publish(String(data=text))

    def publish_estop(self) -> None:
        self.pub_estop.publish(Bool(data=True))

    def after_cycle(self) -> None:
        self.tap.after_cycle()

    def log_info(self, text: str) -> None:
        self.get_logger().info(text)

    def log_error(self, text: str) -> None:
        self.get_logger().error(text)

    def destroy_node(self):
        if hasattr(self, "tap"):
            self.tap.close()
        path = getattr(self, "values", {}).get("summary_path")
        if path and self.loop is not None:
            write_summary(path, self.loop.summary(), self.get_logger().error)
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(ControllerNode, args=args, name="controller", executor="events"))


if __name__ == "__main__":
    main()
