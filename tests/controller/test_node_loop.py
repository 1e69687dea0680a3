"""node_loop.ControllerLoop decided without ROS: its ports are a recorder of calls."""

from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from pkm_common.causes import TripCause
from pkm_controller.configuration import core_from_parameters
from pkm_controller.controller import ControllerConfig
from pkm_controller.controller_node import NODE_PARAMETERS
from pkm_controller.node_loop import ControllerLoop
from pkm_kinematics import load_machine

ARCHI = load_machine("archi")


class Ports:
    """The node's side: what went out, and the graph's view of who publishes."""

    def __init__(self):
        self.graph = {"drives/state": ["/plant"]}
        self.commands, self.errors = [], []

    def input_publishers(self, topic):
        return list(self.graph.get(topic, []))

    def publish_command(self, command):
        self.commands.append(command)

    def log_error(self, text):
        self.errors.append(text)

    def __getattr__(self, name):          # the other ports: ignored
        return lambda *args, **kwargs: None


def state(stamp_ns: int) -> bytes:
    names = list(ARCHI.model.leg_names)
    msg = JointState(name=names, position=ARCHI.model.inverse_kinematics(ARCHI.model.home).tolist(),
                     velocity=[0.0] * len(names))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return serialize_message(msg)


def test_an_intruder_matched_before_the_graph_knows_its_name_stops_at_once_and_is_named_later():
    ports = Ports()
    loop = ControllerLoop(core_from_parameters("archi", ControllerConfig()),
                          {**NODE_PARAMETERS, "state_source": "/plant"}, ports)
    loop.active = True
    loop.on_state(state(0))
    assert len(ports.commands) == 1 and not loop.core.stopped
    loop.on_matched("drives/state", 2)             # the graph lists only the plant so far
    assert loop.core.stopped and loop.core.stop_cause == TripCause.INTRUDER
    assert loop.core.stop_reason == "2 publishers on drives/state (only /plant may)"
    assert loop.summary()["intruder"] == ""
    ports.graph["drives/state"].append("/rogue")   # the graph learns its name
    loop.sources_checked = 0.0                     # the next check is due
    loop.on_watchdog()
    assert loop.summary()["intruder"] == "/rogue"
    assert ports.errors[-1] == "/rogue publishes on drives/state (only /plant may)"
    assert loop.core.stop_reason == "2 publishers on drives/state (only /plant may)"   # the stop is not re-made


def test_the_plant_alone_is_never_an_intruder():
    ports = Ports()
    loop = ControllerLoop(core_from_parameters("archi", ControllerConfig()), dict(NODE_PARAMETERS), ports)
    loop.active = True
    for k in range(3):
        loop.on_state(state(k * 1_000_000))
        loop.sources_checked = 0.0
        loop.on_watchdog()
    loop.on_matched("drives/state", 1)
    assert not loop.core.stopped and len(ports.commands) == 3
    assert loop.sources[0].source == "/plant"         # no state_source: the one publisher at the first state


def test_a_state_with_a_negative_stamp_is_refused_not_a_crash():
    """A well-typed drives/state stamped before 1970 raised ValueError out of the
    answer (the command's stamp cannot be encoded): the run "failed", exit 1. It is
    refused: the machine stops safely with the input named, and nothing raises."""
    ports = Ports()
    loop = ControllerLoop(core_from_parameters("archi", ControllerConfig()), dict(NODE_PARAMETERS), ports)
    loop.active = True
    loop.on_state(state(0))
    bad = JointState(name=list(ARCHI.model.leg_names), position=[0.0] * 4, velocity=[0.0] * 4)
    bad.header.stamp.sec = -5
    loop.on_state(serialize_message(bad))
    assert loop.core.stopped and loop.core.stop_cause == TripCause.INPUT_REFUSED, loop.core.stop_reason
    assert "header.stamp must be at or after 0 s" in loop.core.stop_reason and "sec -5" in loop.core.stop_reason
