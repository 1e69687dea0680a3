"""node_loop.ControllerLoop decided without ROS: its ports are a recorder of calls."""

from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from pkm_common.causes import TripCause
from pkm_common.cdr import encode_string
from pkm_common.conversions import signed_message
from pkm_common.credential import RunKey, Signer, Verifier
from pkm_controller.configuration import core_from_parameters
from pkm_controller.config import ControllerConfig
from pkm_controller.configuration import NODE_PARAMETERS
from pkm_controller.node_loop import ControllerLoop
from pkm_controller.operator_actions import Action
from pkm_kinematics import load_machine

ARCHI = load_machine("archi")


class Ports:
    """The node's side: what went out, and the graph's view of who publishes."""

    def __init__(self):
        self.graph = {"drives/state": ["/plant"]}
        self.commands, self.errors = [], []

    def input_publishers(self, topic):
        return list(self.graph.get(topic, []))

    def topic_senders(self, topic):
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


def trajectory_bytes(seconds: float = 1.0, signer=None) -> bytes:
    """A 10 mm move in x from home, as trajectory_node publishes it (``signer``: with
    the run's credential)."""
    from pkm_common.conversions import trajectory_msg
    from pkm_trajectory.planner import Limits, Line, plan
    home = list(ARCHI.model.home)
    samples = plan([Line(tuple(home), (home[0] + 0.01, *home[1:]), speed=0.01 / seconds)],
                   Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0)), 1000.0, translation_axes=2)
    msg = trajectory_msg(ARCHI.model.task_space, samples.time_s, samples.position, samples.velocity,
                         samples.acceleration)
    msg.header.stamp.sec = 7                     # the planner's stamp: the verdict names it
    return signed_message(signer, "trajectory", msg)


def commanded_loop(ports, key=None):
    import json
    events = []
    ports.publish_event = lambda text: events.append(json.loads(text))
    loop = ControllerLoop(core_from_parameters("archi", ControllerConfig()),
                          {**NODE_PARAMETERS, "state_source": "/plant", "trajectory_source": "/pkm/trajectory",
                           "operator_sources": "/pkm/panel, /pkm/bringup_monitor"}, ports, Verifier(key))
    loop.active = True
    return loop, events


def test_a_command_from_a_node_the_run_did_not_name_is_refused_and_named():
    """A rogue node in the run's domain moved the tool through trajectory (8 mm, the
    run "completed") and controller/settings (computed torque, prestress 1e9 N). Its
    commands are refused, recorded with its name and counted; holding, the machine holds."""
    ports = Ports()
    loop, events = commanded_loop(ports)
    loop.on_state(state(0))
    ports.graph["trajectory"] = ["/pkm/trajectory", "/pkm/rogue"]
    loop.on_trajectory(trajectory_bytes())
    ports.graph["controller/settings"] = ["/pkm/rogue"]
    loop.on_command("controller/settings", Action.SETTINGS, encode_string('{"bandwidth_hz": 5.0}'))
    assert [(e["kind"], e["ok"], e["intruder"]) for e in events] == [("trajectory", False, "/pkm/rogue"),
                                                                     ("settings", False, "/pkm/rogue")]
    assert events[0]["message"] == ("refused: /pkm/rogue publishes on trajectory (only /pkm/trajectory may: "
                                    "trajectory_source)")
    assert loop.core.mode == "holding" and not loop.core.stopped and loop.core.config.bandwidth_hz == 20.0
    assert loop.summary()["commands_refused"] == {"trajectory": 1, "controller/settings": 1}
    assert loop.summary()["intruder"] == "/pkm/rogue"
    # refused commands do not end the watch on the inputs' sources (it went quiet once the
    # first intruder was named): a rogue on drives/state still stops the machine
    ports.graph["drives/state"] = ["/plant", "/pkm/rogue"]
    loop.sources_checked = 0.0
    loop.on_watchdog()
    assert loop.core.stopped and loop.core.stop_cause == TripCause.INTRUDER and "drives/state" in loop.core.stop_reason



def test_a_command_is_taken_again_once_the_rogue_is_gone():
    ports = Ports()
    loop, events = commanded_loop(ports)
    loop.on_state(state(0))
    ports.graph["trajectory"] = ["/pkm/trajectory", "/pkm/rogue"]
    loop.on_trajectory(trajectory_bytes())
    assert events[-1]["ok"] is False and events[-1]["intruder"] == "/pkm/rogue" and not loop.core.stopped
    ports.graph["trajectory"] = ["/pkm/trajectory"]
    loop.on_trajectory(trajectory_bytes())
    loop.on_state(state(1_000_000))                # applied after the next answer
    assert events[-1]["kind"] == "trajectory" and events[-1]["ok"] and loop.core.mode == "tracking"
    assert events[-1]["stamp_ns"] == 7_000_000_000 and events[-2]["stamp_ns"] == 7_000_000_000


def check_every_command_topic(loop) -> None:
    """The watchdog's checks of the command topics, one a call, each one due."""
    for _ in loop.commands:
        loop.commands_checked = 0.0
        loop.on_watchdog()


def test_a_rogue_commanding_during_a_motion_stops_the_machine():
    ports = Ports()
    loop, events = commanded_loop(ports)
    ports.graph["trajectory"] = ["/pkm/trajectory"]
    loop.on_state(state(0))
    loop.on_trajectory(trajectory_bytes())
    for k in range(1, 4):
        loop.on_state(state(k * 1_000_000))
    assert loop.core.mode == "tracking" and not loop.core.stopped
    ports.graph["controller/feed_override"] = ["/pkm/panel", "/elsewhere/rogue"]       # it publishes
    check_every_command_topic(loop)
    assert loop.core.stopped and loop.core.stop_cause == TripCause.INTRUDER, loop.core.stop_reason
    assert "/elsewhere/rogue publishes on controller/feed_override" in loop.core.stop_reason
    assert any(e["kind"] == "safe_stop" and e["cause"] == "intruder" for e in events)   # in the bag


def test_a_rogue_goal_during_a_motion_stops_the_machine_too():
    """The planner refuses a rogue's goal; the controller, watching the planner's
    inputs during a motion, stops the machine."""
    ports = Ports()
    loop, _ = commanded_loop(ports)
    ports.graph["trajectory"] = ["/pkm/trajectory"]
    loop.on_state(state(0))
    loop.on_trajectory(trajectory_bytes())
    loop.on_state(state(1_000_000))
    ports.graph["goal"] = ["/pkm/panel", "/pkm/rogue"]
    check_every_command_topic(loop)
    assert loop.core.stop_cause == TripCause.INTRUDER and "/pkm/rogue publishes on goal" in loop.core.stop_reason


def test_a_run_without_named_sources_takes_commands_from_anyone():
    """A controller started by hand (no run): its command topics are open, as before."""
    ports = Ports()
    loop = ControllerLoop(core_from_parameters("archi", ControllerConfig()), dict(NODE_PARAMETERS), ports)
    loop.active = True
    loop.on_state(state(0))
    ports.graph["trajectory"] = ["/anyone"]
    loop.on_trajectory(trajectory_bytes())
    loop.on_state(state(1_000_000))
    assert loop.core.mode == "tracking" and loop.summary()["commands_refused"] == {}


def credential_loop(tmp_path):
    """A run's controller with its key, every command topic's publishers named as
    allowed (a rogue that took an allowed name: only the credential tells)."""
    key = RunKey.create(tmp_path / "credential.key")
    ports = Ports()
    loop, events = commanded_loop(ports, key)
    ports.graph.update({"trajectory": ["/pkm/trajectory"], "controller/settings": ["/pkm/panel"],
                        "controller/feed_override": ["/pkm/panel"], "run/start": ["/pkm/bringup_monitor"]})
    return key, loop, events


def test_with_the_runs_key_a_command_without_its_credential_is_refused_whatever_its_name(tmp_path):
    key, loop, events = credential_loop(tmp_path)
    panel = Signer(key, "/pkm/panel")
    loop.on_state(state(0))
    loop.on_command("controller/settings", Action.SETTINGS, encode_string('{"bandwidth_hz": 5.0}'))
    loop.on_trajectory(trajectory_bytes())                               # unsigned: a spoofed planner
    other = Signer(RunKey.create(tmp_path / "old.key"), "/pkm/trajectory")   # an earlier run's planner
    loop.on_trajectory(trajectory_bytes(signer=other))
    assert [(e["kind"], e["ok"], e["intruder"]) for e in events] == [
        ("settings", False, "(no credential)"), ("trajectory", False, "(no credential)"),
        ("trajectory", False, "(no credential)")]
    assert events[0]["message"] == "refused: controller/settings: no credential (pkm-cred/1 tag) in the message"
    assert "not valid for this run (says /pkm/trajectory)" in events[2]["message"]
    assert "stamp_ns" not in events[1]        # an unsigned stamp is not believed (the planner's chain matches by it)
    assert loop.core.config.bandwidth_hz == 20.0 and loop.core.mode == "holding"
    signed = panel.text("controller/settings", '{"bandwidth_hz": 5.0}')
    loop.on_command("controller/settings", Action.SETTINGS, signed)
    loop.on_state(state(1_000_000))                                    # applied after the next answer
    assert events[-1]["kind"] == "settings" and events[-1]["ok"] and loop.core.config.bandwidth_hz == 5.0
    loop.on_command("controller/settings", Action.SETTINGS, signed)     # recorded off the wire, sent again
    assert events[-1]["ok"] is False and "a replayed command of /pkm/panel" in events[-1]["message"]
    # the planner may not send settings, though it holds the key
    loop.on_command("controller/settings", Action.SETTINGS,
                    Signer(key, "/pkm/trajectory").text("controller/settings", "{}"))
    assert "/pkm/trajectory holds the run's credential but may not send it" in \
        events[-1]["message"]
    assert loop.summary()["commands_refused"] == {"controller/settings": 3, "trajectory": 2}
    assert not loop.core.stopped


def test_with_the_runs_key_the_signed_trajectory_runs_and_a_forged_command_stops_the_motion(tmp_path):
    key, loop, events = credential_loop(tmp_path)
    loop.on_state(state(0))
    loop.on_trajectory(trajectory_bytes(signer=Signer(key, "/pkm/trajectory")))
    loop.on_command("controller/feed_override", Action.FEED_OVERRIDE,
                    Signer(key, "/pkm/panel").text("controller/feed_override", "0.5"))
    for k in range(1, 4):
        loop.on_state(state(k * 1_000_000))
    assert loop.core.mode == "tracking" and not loop.core.stopped
    assert [e["value"] for e in events if e["kind"] == "feed_override"] == [0.5]
    loop.on_command("controller/feed_override", Action.FEED_OVERRIDE, encode_string("2.0"))
    assert loop.core.stopped and loop.core.stop_cause == TripCause.INTRUDER
    assert loop.core.stop_reason == "controller/feed_override: no credential (pkm-cred/1 tag) in the message"
    assert any(e["kind"] == "safe_stop" and e["cause"] == "intruder" for e in events)


def test_a_command_refused_before_the_graph_names_its_sender_is_named_later(tmp_path):
    key, loop, events = credential_loop(tmp_path)
    loop.on_command("controller/settings", Action.SETTINGS, encode_string("{}"))
    assert events[-1]["intruder"] == "(no credential)" and loop.summary()["intruder"] == "(no credential)"
    loop.on_watchdog()                                     # the graph still names only the panel
    assert loop.summary()["intruder"] == "(no credential)"
    loop.ports.graph["controller/settings"] = ["/pkm/panel", "/pkm/rogue"]
    loop.commands_checked = 0.0
    loop.on_watchdog()
    assert loop.summary()["intruder"] == "/pkm/rogue" and loop.unnamed_commands == {}


def test_a_signed_feed_override_that_is_no_number_is_refused_and_the_start_needs_its_credential(tmp_path):
    key, loop, events = credential_loop(tmp_path)
    loop.values["wait_for_start"] = True
    loop.on_command("controller/feed_override", Action.FEED_OVERRIDE,
                    Signer(key, "/pkm/panel").text("controller/feed_override", "fast"))
    assert events[-1]["ok"] is False and events[-1]["message"] == \
        "controller/feed_override: expected a number, got 'fast'"
    loop.on_start(encode_string("start"))
    assert not loop.start_received
    loop.on_start(Signer(key, "/pkm/bringup_monitor").text("run/start", "start"))
    assert loop.start_received


def test_an_estop_before_the_first_cycle_of_a_six_axis_machine_is_reported():
    """The panel's hexapod graph, E-stopped before it started: the controller crashed
    making its status (a 3-element error on a 6-DOF machine), and its summary with it."""
    import json
    events = []
    ports = Ports()
    ports.publish_event = lambda text: events.append(json.loads(text))
    loop = ControllerLoop(core_from_parameters("hexapod8", ControllerConfig(strategy="computed_torque")),
                          dict(NODE_PARAMETERS), ports)
    loop.active = True
    loop.on_estop(True)
    level, message, values = loop.core.status()
    assert (level, message, values["tracking_error_rad"]) == (2, "stopped: estop", 0.0)
    assert (loop.summary()["cause"], loop.summary()["stopped"]) == ("estop", True)
    assert events[-1]["kind"] == "safe_stop" and events[-1]["cause"] == "estop"


def test_a_bogus_trajectory_is_refused_for_what_it_is_and_the_machine_holds():
    """A 2 m/s trajectory from rest was accepted, and the trip that followed was named
    encoder_fault (issue 40): refused now at its arrival, with its reason, recorded."""
    from pkm_common.conversions import trajectory_msg
    ports = Ports()
    loop, events = commanded_loop(ports)
    ports.graph["trajectory"] = ["/pkm/trajectory"]
    loop.on_state(state(0))
    t = [k * 0.001 for k in range(100)]
    home = list(ARCHI.model.home)
    position = [[home[0] + 2.0 * tk, home[1], home[2]] for tk in t]
    msg = trajectory_msg(ARCHI.model.task_space, t, position, [[2.0, 0.0, 0.0]] * 100, [[0.0] * 3] * 100)
    loop.on_trajectory(serialize_message(msg))
    loop.on_state(state(1_000_000))
    assert events[-1]["kind"] == "trajectory" and events[-1]["ok"] is False, events
    assert events[-1]["message"].startswith("trajectory: it starts moving (point 0, task axis 0 at 2 per s)")
    assert loop.core.mode == "holding" and not loop.core.stopped
