"""The operator panel's core (pkm_operator.panel, no ROS, no browser): every action is
validated before anything is published (the field and its range named), motion only
while the machine holds still, the E-stop latched; the jog watchdog holds a jog whose
page fell silent; the drawing against the machine's own geometry; the tracking error
of the plot paired by step."""

import json
import math
import re

import numpy as np
import pytest

from pkm_operator.panel import HEARTBEAT_TIMEOUT_S, Panel, PanelModel
from pkm_common.poses import machine_pose_components
from pkm_kinematics.task_space import PLANAR, SPATIAL
from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine

ARCHI = load_machine("archi")
MOM3 = load_machine("mom3")
HOME = ARCHI.model.home.tolist()
HOLDING = {"mode": "holding", "strategy": "decentralized_projected", "distribution": "inf_norm", "p_norm": 4.0,
           "prestress_n": 0.0, "bandwidth_hz": 20.0, "damping_ratio": 1.0, "integral_time_s": 0.05, "dt_s": 0.004}


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def live_panel(reference=HOME, **kwargs):
    """A panel that has heard a holding controller at ``reference``."""
    clock = Clock()
    panel = Panel(PanelModel(ARCHI), clock=clock, **kwargs)
    panel.on_status("controller", 0, "holding", dict(HOLDING))
    position, orientation = machine_pose_components(PLANAR, reference)
    panel.on_reference(1_000_000, position, orientation)
    return panel, clock


def test_the_model_knows_each_machines_axes_and_workspace():
    archi, mom3 = PanelModel(ARCHI).describe(), PanelModel(MOM3).describe()
    assert archi["axes"] == ["x", "y", "theta"] and mom3["axes"] == ["x", "y", "z"]
    assert archi["workspace"] == [[0.6, 1.4], [-0.6, -0.25]]
    np.testing.assert_allclose(mom3["workspace"], [[-0.15, 0.15], [-0.15, 0.15], [0.732, 1.032]], atol=1e-12)
    assert archi["drives"] == ["q1", "q2", "q3", "q4"]


def test_the_drawing_has_the_legs_and_struts_of_the_machines_geometry():
    """Each ARCHI leg drawn is as long as its link (config), each strut as long as the
    Gough model's own length at that pose."""
    pose = [1.05, -0.42, 0.9]
    drawing = PanelModel(ARCHI).drawing(pose)
    lengths = [math.dist(a, b) for a, b in drawing["legs"]]
    np.testing.assert_allclose(lengths, [1.0] * 4, atol=1e-12)
    position, orientation = machine_pose_components(PLANAR, pose)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    struts = [math.dist(a, b) for a, b in drawing["struts"]]
    expected = GoughSensorModel(ARCHI.metrology).true_lengths(position, [[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(struts, expected, atol=1e-12)
    assert len(drawing["platform"]) == 4
    assert PanelModel(ARCHI).drawing(pose, struts=False)["struts"] == []


def test_a_jog_moves_the_reference_by_its_step_inside_the_workspace():
    panel, _ = live_panel()
    result = panel.handle({"type": "jog", "axis": "y", "step": -0.004}, "page")
    assert result.ok and result.publish[0][0] == "goal"
    np.testing.assert_allclose(result.publish[0][1], [HOME[0], HOME[1] - 0.004, HOME[2]], atol=1e-12)
    again = panel.handle({"type": "jog", "axis": "x", "step": 0.001}, "page")      # the first one still runs
    assert not again.ok and "holding still, it is jogging" in again.message and again.publish == []


@pytest.mark.parametrize("action, message", [
    ({"type": "jog", "axis": "z", "step": 0.001}, r"jog: axis must be one of \['x', 'y', 'theta'\], got 'z'"),
    ({"type": "jog", "axis": "x", "step": 0.5}, r"jog: step must be a number with 0 < \|step\| <= 0.01 m"),
    ({"type": "jog", "axis": "x", "step": True}, r"jog: step must be a number"),
    ({"type": "jog", "axis": "x", "step": float("nan")}, r"jog: step must be a number"),
    ({"type": "jog", "axis": "theta", "step": 0.2}, r"0 < \|step\| <= 0.1 rad"),
    ({"type": "jog", "axis": "y", "step": 0.01}, r"jog: y would reach -0.2450 m, outside the workspace "
                                                 r"\[-0.6, -0.25\] m"),
    ({"type": "feed", "percent": 150}, r"feed: percent must be a number in \[0, 100\], got 150"),
    ({"type": "feed", "percent": "fast"}, r"feed: percent must be a number in \[0, 100\]"),
    ({"type": "settings", "changes": {"bandwidth_hz": 500}}, r"bandwidth_hz must be a number in \[0.5, 100\]"),
    ({"type": "settings", "changes": {"bandwidth_hz": 50}}, r"bandwidth_hz: must be in \(0, 25\] Hz"),
    ({"type": "settings", "changes": {"strategy": "sensor_space"}}, r"strategy: sensor_space feeds back struts"),
    ({"type": "settings", "changes": {"force_limit_n": 1.0}}, r"'force_limit_n' is not a runtime setting"),
    ({"type": "settings", "changes": []}, r"settings: changes must be a non-empty object"),
    ({"type": "program", "text": "G1 X10 E4\n"}, r"line 1: E4: unsupported word E"),
    ({"type": "program", "text": "  "}, r"program: text must be non-empty G-code"),
    ({"type": "start"}, r"start: load a program first"),
    ({"type": "teleport"}, r"type: must be one of estop, reset, program"),
    ({"kind": "jog"}, r"action: expected a JSON object with a 'type'"),
])
def test_bad_input_is_refused_with_its_range_and_nothing_is_published(action, message):
    panel, _ = live_panel(reference=[HOME[0], -0.255, HOME[2]])
    result = panel.handle(action, "page")
    assert not result.ok and result.publish == []
    assert re.search(message, result.message), result.message
    assert panel.snapshot()["actions"][-1]["ok"] is False        # logged too


def test_motion_waits_for_the_machine_to_hold_still():
    panel, _ = live_panel()
    panel.on_status("controller", 0, "tracking", {**HOLDING, "mode": "tracking"})
    assert panel.handle({"type": "program", "text": "G91 G1 X10 F600\n"}, "page").ok     # loading is fine
    for action in ({"type": "start"}, {"type": "jog", "axis": "x", "step": 0.001}):
        result = panel.handle(action, "page")
        assert not result.ok and "must be holding still, it is tracking" in result.message
    panel.on_status("controller", 0, "holding", dict(HOLDING))
    start = panel.handle({"type": "start"}, "page")
    assert start.ok and start.publish == [("program", "G91 G1 X10 F600\n")]


def test_the_estop_latches_needs_no_token_and_only_a_reset_clears_it():
    panel, _ = live_panel(can_reset=True)
    assert not panel.handle({"type": "feed", "percent": 50}, "viewer", authorized=False).ok
    stop = panel.handle({"type": "estop"}, "viewer", authorized=False)
    assert stop.ok and stop.publish == [("estop", True)]
    refused = panel.handle({"type": "feed", "percent": 50}, "page")
    assert not refused.ok and refused.message.startswith("E-stop latched (E-stop pressed on the panel (viewer))")
    reset = panel.handle({"type": "reset"}, "page")
    assert reset.ok and reset.restart and reset.publish == [("estop", False)]
    assert not panel.snapshot()["estop"]["latched"]
    panel_without_graph, _ = live_panel()
    panel_without_graph.handle({"type": "estop"}, "page")
    refused = panel_without_graph.handle({"type": "reset"}, "page")
    assert not refused.ok and "start a new run" in refused.message


def test_a_controller_that_stops_latches_the_panel_with_its_reason():
    panel, _ = live_panel()
    panel.on_status("controller", 2, "stopped: following error 10.2 mm", {**HOLDING, "mode": "stopped"})
    snap = panel.snapshot()["estop"]
    assert snap["latched"] and "following error 10.2 mm" in snap["why"]


def test_an_action_whose_reader_is_not_discovered_yet_is_refused_not_lost():
    """A goal published before the planner's subscription is matched is lost (volatile):
    the panel said "done jog" and nothing moved (a suite's hexapod panel test). Now an
    action is refused, naming the topic and its reader, until a subscriber is matched;
    the refused jog leaves no jog running, and the next one, once matched, goes out."""
    panel, _ = live_panel()
    subscribers = {"goal": 0, "program": 0, "controller/feed_override": 1, "controller/settings": 1}
    readers = {"goal": "trajectory", "program": "trajectory", "controller/feed_override": "controller",
               "controller/settings": "controller"}
    panel.connect(lambda topic, node: subscribers[topic] if readers[topic] == node else 0)
    assert panel.snapshot()["unreached"] == ["start", "jog"]
    refused = panel.handle({"type": "jog", "axis": "y", "step": -0.004}, "page")
    assert not refused.ok and refused.publish == [] and refused.message == (
        "jog: not sent: the planner (trajectory_node) does not read goal yet (not discovered, or not matched); "
        "try again")
    assert panel.snapshot()["jog"] is None
    assert panel.handle({"type": "feed", "percent": 50}, "page").ok           # the controller is there
    subscribers["goal"] = 1
    assert panel.snapshot()["unreached"] == ["start"]
    result = panel.handle({"type": "jog", "axis": "y", "step": -0.004}, "page")
    assert result.ok and result.publish[0][0] == "goal"
    subscribers.update({"controller/feed_override": 0, "controller/settings": 0})
    estop = panel.handle({"type": "estop"}, "page")                           # never held back
    assert estop.ok and estop.publish == [("estop", True)]


def test_a_jog_is_held_when_its_page_falls_silent_and_ends_when_it_arrives():
    panel, clock = live_panel()
    target = panel.handle({"type": "jog", "axis": "x", "step": 0.002}, "page").publish[0][1]
    for _ in range(5):                       # heartbeats every 0.1 s: nothing happens
        clock.t += 0.1
        panel.handle({"type": "heartbeat"}, "page")
        assert panel.watchdog() is None
    clock.t += HEARTBEAT_TIMEOUT_S + 0.01
    held = panel.watchdog()
    assert held is not None and held.publish == [("controller/feed_override", 0.0)]
    assert "silent for more than 0.5 s" in held.message and panel.watchdog() is None    # once
    # a jog that arrives is over: a silent page afterwards holds nothing
    panel, clock = live_panel()
    target = panel.handle({"type": "jog", "axis": "x", "step": 0.002}, "page").publish[0][1]
    position, orientation = machine_pose_components(PLANAR, target)
    panel.on_reference(2_000_000, position, orientation)
    assert panel.watchdog() is None and panel.snapshot()["jog"] is None
    clock.t += 10.0
    assert panel.watchdog() is None
    # a page that closes during a jog: held at once
    panel, clock = live_panel()
    panel.handle({"type": "jog", "axis": "x", "step": 0.002}, "page")
    panel.disconnected("page")
    assert "connection closed" in panel.watchdog().message


def test_settings_go_out_as_json_after_the_controllers_own_check():
    panel, _ = live_panel()
    result = panel.handle({"type": "settings", "changes": {"strategy": "joint_pid", "bandwidth_hz": 12.5}}, "page")
    assert result.ok and result.publish == [("controller/settings", json.dumps({"strategy": "joint_pid",
                                                                                 "bandwidth_hz": 12.5}))]
    # integral_time_s must stay above 1 / (2 zeta omega) of the gains it runs with
    low = panel.handle({"type": "settings", "changes": {"integral_time_s": 0.001}}, "page")
    assert not low.ok and "integral_time_s: must be 0, or in (0.003979" in low.message


def test_the_plot_pairs_reference_and_pose_of_the_same_step_in_either_order():
    panel, _ = live_panel()
    for k, (first, dy) in enumerate([("pose", 5e-6), ("reference", 12e-6), ("pose", 1e-6)]):
        stamp = (k + 2) * 100_000_000
        ref = machine_pose_components(PLANAR, HOME)
        pose = machine_pose_components(PLANAR, [HOME[0], HOME[1] + dy, HOME[2]])
        calls = [lambda: panel.on_true_pose(stamp, *pose), lambda: panel.on_reference(stamp, *ref)]
        for call in (calls if first == "pose" else calls[::-1]):
            call()
        panel.on_reference(stamp + 50_000_000, *ref)            # an unpaired step in between: not plotted
    plot = panel.snapshot()["plot"]
    assert [round(t, 1) for t, _ in plot] == [0.2, 0.3, 0.4]
    np.testing.assert_allclose([e for _, e in plot], [5.0, 12.0, 1.0], atol=1e-6)


def test_latencies_from_the_action_to_the_controller_and_to_the_drives():
    panel, clock = live_panel()
    panel.handle({"type": "feed", "percent": 40}, "page")
    clock.t += 0.012
    panel.on_event(json.dumps({"kind": "feed_override", "ok": True, "after_ns": 5, "value": 0.4}))
    panel.handle({"type": "estop"}, "page")
    clock.t += 0.007
    panel.on_state(3_000_000, ["q1"], [0.0], [0.0], [0.0], "")                 # still running
    clock.t += 0.001
    panel.on_state(4_000_000, ["q1"], [0.0], [0.0], [0.0], "safe_stop:estop")   # braked
    # the page presses on three paths: the later presses of the latch (here after the
    # drives braked, whose states may then stop) keep the first press's measurement
    clock.t += 0.002
    again = panel.handle({"type": "estop"}, "http 127.0.0.1:1")
    latency = panel.snapshot()["latency_ms"]
    assert again.ok and again.publish == [("estop", True)]
    assert latency["feed_override"] == pytest.approx(12.0) and latency["estop"] == pytest.approx(8.0)
    assert panel.snapshot()["estop"]["why"] == "E-stop pressed on the panel (page)"


def test_the_panel_refuses_a_machine_it_does_not_draw(capsys):
    from pkm_operator.panel_main import main
    assert main(["--machine", "mom3_imperfect", "--port", "0"]) == 2
    assert "--machine: mom3_imperfect is a parallelograms machine; the panel draws and jogs planar and " \
        "translational and struts machines" in capsys.readouterr().err


def test_a_hexapod_on_the_panel_its_six_axes_its_angles_jogged_in_rad_its_struts_drawn():
    """hexapod8 (kind struts): six axes, a b c bounded in rad; each strut drawn as long
    as the model's strut length at that pose, the Gough's struts as the sensor's; a jog
    of c turns the reference about z, one of 0.2 rad is refused naming the bound."""
    hexapod = load_machine("hexapod8")
    model = PanelModel(hexapod)
    described = model.describe()
    assert described["axes"] == ["x", "y", "z", "a", "b", "c"] and described["angular"] == ["a", "b", "c"]
    assert described["jog_max"] == {"x": 0.01, "y": 0.01, "z": 0.01, "a": 0.1, "b": 0.1, "c": 0.1}
    assert len(described["workspace"]) == 3 and len(described["drives"]) == 8       # the box: translations
    pose = (hexapod.model.home + np.array([0.01, -0.02, 0.005, 0.02, -0.01, 0.05])).tolist()
    drawing = model.drawing(pose)
    np.testing.assert_allclose([math.dist(a, b) for a, b in drawing["legs"]],
                               hexapod.model.inverse_kinematics(pose), atol=1e-12)
    position, orientation = machine_pose_components(SPATIAL, pose)
    p, r = hexapod.model.pose(pose)
    np.testing.assert_allclose([math.dist(a, b) for a, b in drawing["struts"]],
                               GoughSensorModel(hexapod.metrology).true_lengths(p, r), atol=1e-12)
    panel = Panel(model, clock=Clock())
    panel.on_status("controller", 0, "holding", dict(HOLDING))
    home = hexapod.model.home.tolist()
    panel.on_reference(1_000_000, *machine_pose_components(SPATIAL, home))
    result = panel.handle({"type": "jog", "axis": "c", "step": 0.05}, "page")
    assert result.ok and result.message == "jog c +0.05 rad"
    np.testing.assert_allclose(result.publish[0][1], home[:5] + [home[5] + 0.05], atol=1e-12)
    refused = Panel(model, clock=Clock())
    refused.on_status("controller", 0, "holding", dict(HOLDING))
    refused.on_reference(1_000_000, *machine_pose_components(SPATIAL, home))
    too_far = refused.handle({"type": "jog", "axis": "a", "step": 0.2}, "page")
    assert not too_far.ok and "jog: step must be a number with 0 < |step| <= 0.1 rad" in too_far.message


def test_drives_that_braked_latch_the_panel_even_if_the_controller_still_says_holding():
    """The controller's status is volatile: a panel matched late, or one that lost the
    status that said "stopped", still held "holding" and accepted a jog that the
    stopped controller then refused (a full test run). The drives' status word is on
    every state: a braked plant latches the panel with its cause."""
    panel, _ = live_panel()
    panel.on_state(3_000_000, ["q1"], [0.0], [0.0], [0.0], "")                 # running: nothing latched
    assert not panel.snapshot()["estop"]["latched"]
    panel.on_state(4_000_000, ["q1"], [0.0], [0.0], [0.0], "safe_stop:deadline_missed")
    snap = panel.snapshot()
    assert snap["controller"]["values"]["mode"] == "holding"                  # the controller's last word
    assert snap["estop"]["latched"] and snap["estop"]["why"] == "the drives braked: deadline_missed"
    refused = panel.handle({"type": "jog", "axis": "x", "step": 0.001}, "page")
    assert not refused.ok and refused.publish == [] and "deadline_missed" in refused.message


def test_after_a_reset_the_ended_runs_last_words_do_not_latch_the_new_one():
    """A reset restarts the graph: until the old one has ended, it still publishes its
    braked states and "stopped" statuses. They must not latch the panel of the new
    run; once restarted, a braked drive latches again."""
    from pkm_operator.panel_main import Graph
    panel, _ = live_panel(can_reset=True)
    panel.handle({"type": "estop"}, "page")
    order = []
    graph = Graph("scenario.yaml", "runs")
    graph.stop = lambda: (order.append("stop"), panel.on_state(9, ["q1"], [0.0], [0.0], [0.0], "safe_stop:estop"),
                          panel.on_status("controller", 2, "stopped: estop", {**HOLDING, "mode": "stopped"}),
                          panel.on_estop(True))
    graph.start = lambda: order.append("start")
    assert panel.handle({"type": "reset"}, "page").restart
    for action in ({"type": "reset"}, {"type": "feed", "percent": 50}):     # not to the old graph, not twice
        refused = panel.handle(action, "page")
        assert not refused.ok and refused.publish == [] and "restarting" in refused.message
    graph.restart(panel.restarted)
    snap = panel.snapshot()
    assert order == ["stop", "start"] and not snap["estop"]["latched"], snap["estop"]
    assert snap["controller"]["message"] == "restarting" and snap["pose"] is None and "t_s" not in snap
    panel.on_state(1_000_000, ["q1"], [0.0], [0.0], [0.0], "safe_stop:following_error")     # the new run's
    assert panel.snapshot()["estop"]["why"] == "the drives braked: following_error"


def test_a_reset_whose_stop_fails_still_listens_to_the_graph():
    """Until restarted() the panel ignores the graph: a stop that raised must not leave
    it deaf to every later stop."""
    from pkm_operator.panel_main import Graph
    panel, _ = live_panel(can_reset=True)
    graph = Graph("scenario.yaml", "runs")

    def stop():
        raise OSError("no such process")
    graph.stop, graph.start = stop, lambda: None
    assert panel.handle({"type": "reset"}, "page").restart
    with pytest.raises(OSError):
        graph.restart(panel.restarted)
    panel.on_state(1_000_000, ["q1"], [0.0], [0.0], [0.0], "safe_stop:watchdog")
    assert panel.snapshot()["estop"]["why"] == "the drives braked: watchdog"


_PANEL_THAT_DIES = """
import sys, time
from pkm_operator.panel_main import Graph
graph = Graph("scenario.yaml", "runs")
graph.command = [sys.executable, "-c", "import time; time.sleep(60)"]    # stands for pkm-run
graph.start()
print(graph.process.pid, flush=True)
time.sleep(60)
"""


def test_the_graph_a_panel_started_dies_with_the_panel_even_killed():
    """An orphan graph would hold the machine, and its DDS domain, with nobody to stop it."""
    import os
    import subprocess
    import sys
    import time
    panel = subprocess.Popen([sys.executable, "-c", _PANEL_THAT_DIES], stdout=subprocess.PIPE, text=True)
    try:
        graph_pid = int(panel.stdout.readline())
        os.kill(graph_pid, 0)                          # running
        panel.kill()
        panel.wait()
        end = time.monotonic() + 10.0
        while time.monotonic() < end:
            try:
                os.kill(graph_pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.05)
        else:
            os.kill(graph_pid, 9)
            pytest.fail("the graph outlived its panel by 10 s")
    finally:
        panel.kill()
        panel.wait()


def test_the_servo_drives_cia402_states_and_error_codes_are_shown():
    """drives/cia402 (pkm_drives.drives_node): each drive's state, statusword and error
    code on the page; a sim_hw run has none (the table hidden); a reset forgets them."""
    panel, _ = live_panel()
    assert panel.snapshot()["cia402"] == {}
    ok = {"node_id": 1.0, "statusword": "0x1237", "error_code": "0x0000", "error": "none",
          "homing": "homed (method 19)"}
    fault = {"node_id": 3.0, "statusword": "0x0208", "error_code": "0x2310", "error": "0x2310 continuous over-current"}
    panel.on_drive_states([("q1", 0, "operation enabled", ok), ("q3", 2, "fault", fault)])
    shown = panel.snapshot()["cia402"]
    assert shown["q1"] == {"level": 0, "state": "operation enabled", "node_id": 1.0, "statusword": "0x1237",
                           "error": "none", "homing": "homed (method 19)"}
    assert shown["q3"]["state"] == "fault" and shown["q3"]["error"] == "0x2310 continuous over-current"
    assert shown["q3"]["level"] == 2
    json.dumps(panel.snapshot())                   # what the page gets
    panel.restarted()
    assert panel.snapshot()["cia402"] == {}
