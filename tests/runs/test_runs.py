"""Whole runs through pkm-run: recording, replay, determinism, shutdown, crashes.

The in-process run (one executor, a few seconds) is shared by the fast tests; the
multi-process ones are marked slow (each starts five Python processes).
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pkm_kinematics.task_space import POSITION

from pkm_bringup.orchestrator import EXIT_CODES, run_scenario
from pkm_bringup.processes import node_pids
from pkm_runs.replay import replay_controller
from pkm_bringup.scenario import load_scenario
from terminal import default_sigint      # tests/terminal.py

SHORT = {"duration_s": 0.8}          # MoM3 square (sensor space, 110 N from 0.3 s), first 0.8 s


def _pkm_run(*args, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "pkm_bringup.orchestrator", *args, "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=default_sigint, **kwargs)


def _leftovers(run_dir: Path) -> list[str]:
    """Live node processes of the run ("<pid>: <node>"; processes.node_pids)."""
    return [f"{pid}: {name}" for name, pid in node_pids(run_dir).items()]


def _held_archi_demo(tmp_path: Path) -> str:
    """archi_demo held 15 s after its motion, for a test that acts on the run a second
    or so into its loop: the shipped ~5 s simulated had ended within that second on a
    quiet machine, and the test met the run's own end."""
    import yaml

    from pkm_kinematics.config import config_dir
    scenario = yaml.safe_load((config_dir() / "scenarios" / "archi_demo.yaml").read_text())
    scenario.update(program=str(config_dir() / "programs" / "archi_test_motion.nc"), settle_s=15.0)
    (tmp_path / "held.yaml").write_text(yaml.safe_dump(scenario))
    return str(tmp_path / "held.yaml")


def _wait_running(run_dir: Path, proc, timeout_s: float = 90.0) -> None:
    """Until the loop runs: the plant has its first command. (The controller's
    "trajectory accepted" is not enough: on a loaded machine the first answer came over
    a second later, and an interrupt a second after it found one recorded step.)"""
    log = run_dir / "logs" / "sim_hw.log"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        if log.exists() and "loop started" in log.read_text(errors="replace"):
            return
        time.sleep(0.1)
    out = proc.communicate(timeout=30)[0] if proc.poll() is not None else ""
    raise AssertionError(f"the run did not start (pkm-run exit code {proc.poll()}); its output:\n{out}")


def _commands(run_dir: Path) -> dict:
    from pkm_runs.replay import recorded_messages
    return {c.header.stamp.sec * 10**9 + c.header.stamp.nanosec: list(c.effort)
            for _, _, c in recorded_messages(run_dir / "bag", "/pkm", ("drives/command",))}


@pytest.fixture(scope="module")
def in_process_run(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("runs") / "mom3_in_process"
    run = run_scenario(load_scenario("mom3_square", SHORT), run_dir, in_process=True, progress=False)
    return run_dir, run


def test_in_process_run_completes_and_loses_nothing(in_process_run):
    run_dir, run = in_process_run
    assert run["status"] == "completed", run["error"]
    sim = run["summaries"]["sim_hw"]
    assert sim["steps"] == 800 and not sim["stopped"]
    # every stream: one message per step published, all of them recorded
    for topic in ("/pkm/drives/state", "/pkm/drives/command", "/pkm/platform/true_pose", "/pkm/metrology/struts",
                  "/pkm/controller/reference", "/clock"):
        assert run["published"][topic] == 801, topic
        assert run["lost"][topic] == 0, topic
    assert run["sensor_missed_steps"] == 0 and run["cause"] == "none"     # stated, here none
    # the loop's streams came through the nodes' recording taps, not subscriptions,
    # and the tap's own batches are not in the bag
    recorder = run["summaries"]["recorder"]
    assert set(recorder["tapped"]) == {"/pkm/drives/state", "/pkm/drives/command", "/pkm/platform/true_pose",
                                       "/pkm/metrology/struts", "/pkm/metrology/pose", "/pkm/controller/reference",
                                       "/clock"}
    assert recorder["tap_errors"] == 0 and not any("_recorder" in t for t in recorder["recorded"])
    # one process: the taps hand their records over as lists (NodeTap.sink), no batch message
    assert recorder["tap_lists"] > 0 and recorder["tap_batches"] == 0
    m = run["metrics"]
    assert m["messages"]["lost_total"] == 0
    assert not m["controller"]["tripped"]
    # sensor-space control, 110 N ramped in over 0.3-0.4 s on a 0.7 um/N structure: a
    # transient of ~410 um (the 20 Hz loop rejecting the load; computed torque: 486 um
    # and the 77 um deflection stays), then the Gough struts remove the deflection
    from pkm_runs.report import load_run, tracking_errors
    assert m["tracking_error"]["max_m"] < 600e-6
    errors = tracking_errors(load_run(run_dir), POSITION)
    late = errors["translation"][errors["stamp_ns"] >= 650 * 10**6]
    assert len(late) == 151 and late.max() < 5e-6
    assert (run_dir / "report" / "metrics.json").exists() and (run_dir / "report" / "path.png").exists()


def test_a_run_as_dataframes_has_the_values_rosbags_reads(in_process_run):
    """pkm_runs.runs against rosbags' own deserialisation of the bag: the drive state
    and the true pose of every step (the last message of a stamp, as the report keeps
    it), drives and struts named, and the run's metrics, scenario and status."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    from pkm_runs.runs import open_run
    run_dir, run = in_process_run
    frames = open_run(run_dir)
    state, pose, struts = frames.frame("state"), frames.frame("true_pose"), frames.frame("struts")
    ref_state, ref_pose = {}, {}
    with AnyReader([run_dir / "bag"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            if conn.topic in ("/pkm/drives/state", "/pkm/platform/true_pose"):
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                if conn.topic == "/pkm/drives/state":
                    ref_state[stamp] = (list(msg.name), list(msg.position), list(msg.effort))
                else:
                    ref_pose[stamp] = (msg.pose.position.x, msg.pose.position.y, msg.pose.position.z)
    stamps = sorted(ref_state)
    assert len(state) == len(stamps) == 801 and np.allclose(state.index, np.array(stamps) * 1e-9, atol=0, rtol=0)
    names = ref_state[stamps[0]][0]
    assert list(state.columns[:len(names)]) == [f"position.{n}" for n in names]
    np.testing.assert_array_equal(state[[f"position.{n}" for n in names]].to_numpy(),
                                  [ref_state[t][1] for t in stamps])
    np.testing.assert_array_equal(state[[f"effort.{n}" for n in names]].to_numpy(), [ref_state[t][2] for t in stamps])
    np.testing.assert_array_equal(pose[["x", "y", "z"]].to_numpy(), [ref_pose[t] for t in sorted(ref_pose)])
    assert len([c for c in struts.columns if c.startswith("position.")]) == 6
    assert frames.metrics["tracking_error"]["max_m"] == run["metrics"]["tracking_error"]["max_m"]
    assert frames.scenario["name"] == "mom3_square" and frames.info["status"] == "completed"
    with pytest.raises(ValueError, match="stream: one of state, command"):
        frames.frame("speed")


def test_recording_reads_the_same_with_rosbags_and_mcap(in_process_run):
    """rosbags AnyReader and mcap + mcap_ros2 see the same messages with the same content."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    run_dir, run = in_process_run
    bag = run_dir / "bag"
    a_counts, a_pos = {}, []
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            a_counts[conn.topic] = a_counts.get(conn.topic, 0) + 1
            if conn.topic == "/pkm/drives/state":
                a_pos.append(list(reader.deserialize(raw, conn.msgtype).position))
    b_counts, b_pos = {}, []
    (mcap_file,) = bag.glob("*.mcap")
    with mcap_file.open("rb") as fh:
        for schema, channel, _, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            b_counts[channel.topic] = b_counts.get(channel.topic, 0) + 1
            if channel.topic == "/pkm/drives/state":
                b_pos.append(list(msg.position))
    assert a_counts == b_counts and a_counts["/pkm/drives/state"] >= 801
    assert a_pos == b_pos
    assert {k: v for k, v in run["summaries"]["recorder"]["recorded"].items() if v} == a_counts


def test_offline_replay_reproduces_every_command_exactly(in_process_run):
    run_dir, _ = in_process_run
    result = replay_controller(run_dir)
    assert result.commands == 801
    assert result.ok and result.identical == result.compared == 801 and result.max_abs_diff_n == 0.0


def test_the_replay_drives_the_controller_nodes_own_loop(in_process_run, monkeypatch):
    """Not a copy of the node's logic: every replayed command is the answer of a
    node_loop.ControllerLoop (the class controller_node drives) to the recorded bytes
    of its state and its Gough reading (mom3_square: sensor space)."""
    from pkm_controller.node_loop import ControllerLoop
    seen = {"on_state": 0, "on_metrology": 0, "answer": 0}
    for name in seen:
        real = getattr(ControllerLoop, name)

        def spy(self, *args, _real=real, _name=name):
            seen[_name] += 1
            if _name != "answer":
                assert isinstance(args[0], bytes), type(args[0])       # the recorded bytes, as the node gets them
            return _real(self, *args)
        monkeypatch.setattr(ControllerLoop, name, spy)
    result = replay_controller(in_process_run[0])
    assert result.ok and result.compared == 801, result
    # the plant repeats its first state until it is answered: a repeat recorded after the
    # answer reached the node too, which prepared it and left it (one under load, seen):
    # the replay hands it over as well
    from pkm_common import topics
    from pkm_common.cdr import stamp_ns_of
    from pkm_runs.replay import recorded_bytes
    states = [stamp_ns_of(raw) for _, _, raw in recorded_bytes(in_process_run[0] / "bag", in_process_run[1]["namespace"],
                                                               (topics.DRIVES_STATE,))]
    repeats = len(states) - len(set(states))
    assert (seen["on_metrology"], seen["answer"]) == (801, 801), seen
    assert 801 <= seen["on_state"] <= 801 + repeats, (seen, repeats)


def test_offline_replay_detects_a_changed_law(in_process_run, tmp_path):
    """The check can fail: the same data with another bandwidth gives other commands."""
    import shutil
    run_dir, _ = in_process_run
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    params = copy / "params" / "controller.yaml"
    params.write_text(params.read_text().replace("bandwidth_hz: 20.0", "bandwidth_hz: 21.0"))
    result = replay_controller(copy)
    assert not result.ok and result.first_mismatch is not None and result.max_abs_diff_n > 0.1


def test_player_republishes_the_recording(in_process_run, ros_context):
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from pkm_recording.player_node import PlayerNode
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    run_dir, run = in_process_run
    deep = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)   # as fast as possible: no drop
    executor = EventsExecutor(context=ros_context)
    listener = rclpy.create_node("listener", context=ros_context)
    stamps = []
    listener.create_subscription(JointState, "/pkm/drives/state",
                                 lambda m: stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
                                 deep)
    player = PlayerNode(context=ros_context, parameter_overrides=[
        Parameter("bag", value=str(run_dir / "bag")), Parameter("rate", value=0.0),
        Parameter("topics", value="/pkm/drives/state"), Parameter("shutdown_on_end", value=False)])
    for node in (listener, player):
        executor.add_node(node)
    try:
        deadline = time.monotonic() + 30
        expected = run["summaries"]["recorder"]["recorded"]["/pkm/drives/state"]
        while len(stamps) < expected and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        player.destroy_node()
        listener.destroy_node()
    assert len(stamps) == expected
    assert stamps == sorted(stamps) and stamps[-1] == 800 * 10**6


@pytest.mark.slow
def test_processes_compute_the_same_run_as_in_process(in_process_run, tmp_path):
    """Lockstep is deterministic: five processes over DDS give bit-identical commands."""
    run_dir, _ = in_process_run
    proc_dir = tmp_path / "mom3_processes"
    run = run_scenario(load_scenario("mom3_square", SHORT), proc_dir, in_process=False, progress=False)
    assert run["status"] == "completed", run["error"]
    assert run["lost"] and all(v == 0 for v in run["lost"].values()), run["lost"]
    recorder = run["summaries"]["recorder"]
    assert recorder["tap_batches"] > 0 and recorder["tap_lists"] == 0     # processes: batch messages
    a, b = _commands(run_dir), _commands(proc_dir)
    assert len(a) == 801 and a == b
    assert not _leftovers(proc_dir)


@pytest.mark.slow
def test_a_composed_loop_computes_the_same_run_as_in_process(in_process_run, tmp_path):
    """The loop's nodes composed in one process (loop_process: composed,
    pkm_bringup.composed_loop), the recorder and the planner in their own: the same
    commands bit for bit, every node's summary, no node left."""
    run_dir, _ = in_process_run
    proc_dir = tmp_path / "mom3_composed"
    run = run_scenario(load_scenario("mom3_square", {**SHORT, "loop_process": "composed"}), proc_dir,
                       in_process=False, progress=False)
    assert run["status"] == "completed", run["error"]
    assert run["lost"] and all(v == 0 for v in run["lost"].values()), run["lost"]
    assert set(run["exit_codes"]) == {"recorder", "loop", "trajectory"} and not any(run["exit_codes"].values()), \
        run["exit_codes"]
    assert {"sim_hw", "gough_sensor", "controller", "recorder"} <= set(run["summaries"]), sorted(run["summaries"])
    a, b = _commands(run_dir), _commands(proc_dir)
    assert len(a) == 801 and a == b
    assert not _leftovers(proc_dir)


@pytest.mark.slow
def test_archi_demo_runs_to_completion_as_processes(tmp_path):
    """The default scenario (make demo): ARCHI test motion, Gough in the loop, cutting
    load, sensor space + inf-norm, five processes, recorded; replayed exactly."""
    run_dir = tmp_path / "archi_demo"
    proc = _pkm_run("archi_demo", "--run-dir", str(run_dir))
    out, _ = proc.communicate(timeout=400)
    assert proc.returncode == 0, out
    assert "scenario archi_demo" in out and "completed" in out and f"run directory: {run_dir}" in out
    run = json.loads((run_dir / "run.json").read_text())
    m = json.loads((run_dir / "report" / "metrics.json").read_text())
    assert run["summaries"]["sim_hw"]["steps"] == 4956 and not run["summaries"]["sim_hw"]["stopped"]
    assert m["messages"]["lost_total"] == 0 and not m["controller"]["tripped"]
    # in-process run of the same scenario (measured): RMS 23 um, max 133 um (the load ramps)
    assert m["tracking_error"]["rms_m"] < 40e-6 and m["tracking_error"]["max_m"] < 250e-6
    assert m["drive_force"]["peak_commanded_n"] < 400.0
    assert replay_controller(run_dir).ok
    assert not _leftovers(run_dir)


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_interrupted_run_leaves_a_valid_bag_and_no_process(tmp_path, sig):
    run_dir = tmp_path / "interrupted"
    proc = _pkm_run(_held_archi_demo(tmp_path), "--run-dir", str(run_dir))
    _wait_running(run_dir, proc)
    time.sleep(1.0)                                   # in the middle of the motion
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 1 and "interrupted" in out, out
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    with AnyReader([run_dir / "bag"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    run = json.loads((run_dir / "run.json").read_text())
    assert run["status"] == "failed" and "interrupted" in run["error"]
    # the interrupt stopped the machine first (an E-stop), not the plant's watchdog later
    assert run["cause"] == "estop", (run["cause"], run["trip_reason"])
    steps = run["recorded"]["/pkm/drives/state"]          # distinct stamps (discovery repeats once)
    # well before its end; on a failure, whether the loop had stepped (the sim's count) or
    # the recording missed its steps
    assert 100 < steps < round(run["duration_s"] / 0.001) - 1000, \
        (steps, run["published"], run["lost"], run["summaries"].get("sim_hw"), out)
    assert run["recorded"]["/pkm/drives/command"] >= steps - 1
    assert counts["/pkm/drives/state"] >= steps             # the bag itself holds them all
    assert not _leftovers(run_dir)


@pytest.mark.slow
def test_a_crashing_node_is_reported_and_everything_stops(tmp_path):
    run_dir = tmp_path / "crash"
    proc = _pkm_run(_held_archi_demo(tmp_path), "--run-dir", str(run_dir))
    _wait_running(run_dir, proc)
    time.sleep(0.5)
    victims = [line.split(":")[0] for line in _leftovers(run_dir) if line.endswith(": controller")]
    assert len(victims) == 1
    os.kill(int(victims[0]), signal.SIGKILL)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 1
    assert "node controller exited with code -9 (killed by SIGKILL)" in out and "its last output" in out, out
    assert (run_dir / "bag" / "metadata.yaml").exists()        # the recorder still finalized
    assert not _leftovers(run_dir)
    run = json.loads((run_dir / "run.json").read_text())
    assert np.isfinite(run["wall_s"])
    # the kill is the run's cause (it was "none"; the plant's silent-controller stop is its consequence)
    assert run["status"] == "failed" and run["cause"] == "node_died", (run["cause"], run["trip_reason"])
    assert run["trip_reason"] == "node controller exited with code -9 (killed by SIGKILL)", run["trip_reason"]


@pytest.mark.slow
def test_after_a_recorder_kill_the_run_recovers_its_bag_and_reports_the_loss(tmp_path):
    run_dir = tmp_path / "recorder_killed"
    proc = _pkm_run(_held_archi_demo(tmp_path), "--run-dir", str(run_dir))
    _wait_running(run_dir, proc)
    time.sleep(1.5)
    victims = [line.split(":")[0] for line in _leftovers(run_dir) if line.endswith(": recorder")]
    assert len(victims) == 1
    os.kill(int(victims[0]), signal.SIGKILL)
    out, _ = proc.communicate(timeout=90)
    assert proc.returncode == 1 and "node recorder exited with code -9" in out, out
    assert "bag recovered up to its last chunk" in out, out
    run = json.loads((run_dir / "run.json").read_text())
    assert run["recovered"]["messages"] > 1000 and run["summaries"]["recorder"]["recovered"]
    lost = run["lost"]["/pkm/drives/state"]
    assert 0 < lost < run["published"]["/pkm/drives/state"]      # the loss stated, not "100 % lost"
    metrics = json.loads((run_dir / "report" / "metrics.json").read_text())
    assert metrics                                               # the report made from what was saved
    assert not _leftovers(run_dir)


def test_player_steps_one_clock_tick_per_call(in_process_run, ros_context):
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger

    from pkm_recording.player_node import PlayerNode
    run_dir, run = in_process_run
    player = PlayerNode(context=ros_context, parameter_overrides=[
        Parameter("bag", value=str(run_dir / "bag")), Parameter("step", value=True),
        Parameter("topics", value="/clock,/pkm/drives/state")])
    topics = []
    publish = player._publish
    player._publish = lambda item: (topics.append(item[0].topic), publish(item))
    try:
        for _ in range(5):
            before = len(topics)
            response = player.on_step(Trigger.Request(), Trigger.Response())
            assert response.success
            assert topics[before:].count("/clock") == 1       # one simulated-time step per call
        while player.on_step(Trigger.Request(), Trigger.Response()).success:
            pass
        assert topics.count("/clock") == run["summaries"]["recorder"]["recorded"]["/clock"]   # repeats too
    finally:
        player.destroy_node()


def test_realtime_scenario_runs_on_the_wall_clock_and_reports_deadline_misses(tmp_path):
    """mode: realtime — sim_hw steps on its timer from the first command on (zero-order
    hold); misses are counted (the sync error counter, which brakes on too many of them,
    is off: one process on a loaded machine may miss bursts of cycles)."""
    plant = {**load_scenario("mom3_square").plant, "sync_error_limit": 0}
    s = load_scenario("mom3_square", {"mode": "realtime", "dt_s": 0.002, "duration_s": 0.6, "record": True,
                                      "plant": plant})
    run = run_scenario(s, tmp_path / "rt", in_process=True, progress=False)
    assert run["status"] == "completed", run["error"]
    sim = run["summaries"]["sim_hw"]
    assert sim["steps"] == 300 and not sim["stopped"]
    assert 0.55 <= sim["wall_s"] < 3.0                     # paced by the wall clock (300 x 2 ms), not by the answers
    assert run["metrics"]["deadline_misses"] == sim["deadline_misses"]


def test_a_realtime_run_with_missed_deadlines_replays_bit_for_bit(tmp_path):
    """mom3_square in real time at 5 kHz in one process, which cannot keep that rate
    (the three nodes' cycle takes longer than 0.2 ms; at 2 kHz a fast phase of this VM
    missed only 8 deadlines, some runs over 100): states come before the readings of the one before, the controller prepares
    them and leaves them (the core moves on), and the recorder logs some readings after
    the command that answered them. pkm-replay prepares the left states too and waits
    for late readings: every recorded command is recomputed bit for bit (before: the
    first mismatch at command 1-3, then 'no recorded metrology/struts'). On a loaded
    machine (the suite on two workers) so many deadlines may pass that the supervisor
    stops the machine: the run must replay bit for bit all the same, stop included."""
    plant = {**load_scenario("mom3_square").plant, "sync_error_limit": 0}
    s = load_scenario("mom3_square", {"mode": "realtime", "dt_s": 0.0002, "duration_s": 0.4, "record": True,
                                      "plant": plant})
    run = run_scenario(s, tmp_path / "rt5k", in_process=True, progress=False, report=False)
    assert run["status"] in ("completed", "tripped") and not run["error"], run["error"]
    assert run["summaries"]["sim_hw"]["deadline_misses"] > 20
    result = replay_controller(tmp_path / "rt5k")
    # as many commands as the controller answered (some of the 2000 states get none)
    assert result.ok and result.compared == result.commands >= 20, result


def test_a_tripping_scenario_ends_tripped_and_reports_the_cause(tmp_path):
    """archi_fig12 (joint PIDs, 2 % leg error, no program: a dwell starts the loop after
    the recorder is ready): the drives fight, the supervisor stops the machine; the run
    ends "tripped" with the cause that started the stop (saturation), not "completed",
    and replays bit for bit, the stop included."""
    run = run_scenario(load_scenario("archi_fig12", {"duration_s": 0.8}), tmp_path / "fig12", in_process=True,
                       progress=False)
    assert run["status"] == "tripped" and not run["error"], run["error"]
    assert run["cause"] == "saturation" and "saturated" in run["trip_reason"]
    assert EXIT_CODES[run["status"]] == 3
    assert all(v == 0 for v in run["lost"].values()), run["lost"]
    assert run["metrics"]["controller"]["tripped"]
    assert "saturated" in run["summaries"]["controller"]["message"]
    # the stop is the controller's own: recorded as a safe_stop event and reproduced by the
    # replay, which compares every command, the zeros after the stop included
    result = replay_controller(tmp_path / "fig12")
    assert result.ok and result.compared == result.commands > 100 and "estop" not in result.note, result


def test_a_second_run_of_this_machine_is_refused_whatever_discovery_does(tmp_path, monkeypatch):
    """The run lock, not discovery: a second run in the same domain and namespace is
    refused at once, every time, and its directory holds no node's output."""
    from pkm_bringup.orchestrator import RunLock
    monkeypatch.setattr("pkm_bringup.orchestrator.LOCK_DIR", tmp_path / "locks")
    with RunLock("/pkm"):
        for k in range(3):
            run = run_scenario(load_scenario("mom3_square", SHORT), tmp_path / f"second{k}", in_process=True,
                               progress=False)
            assert run["status"] == "failed" and "another run is active" in run["error"], run["error"]
            assert not run["summaries"]
    with RunLock("/other"):                     # another namespace is another run
        pass


@pytest.mark.slow
def test_a_foreign_publisher_on_drives_command_is_refused_before_the_start(tmp_path, ros_context):
    """A node that publishes on drives/command and sends nothing: named, at once (it used
    to block the run for 60 s, "graph not connected")."""
    import rclpy
    from sensor_msgs.msg import JointState

    from pkm_common.qos import STREAM_QOS
    rogue = rclpy.create_node("rogue", namespace="/pkm", context=ros_context)
    rogue.create_publisher(JointState, "drives/command", STREAM_QOS)
    try:
        start = time.monotonic()
        run = run_scenario(load_scenario("mom3_square", SHORT), tmp_path / "rogue", progress=False)
    finally:
        rogue.destroy_node()
    assert run["status"] == "failed" and "intruder: /pkm/rogue publishes on /pkm/drives/command" in run["error"]
    assert time.monotonic() - start < 30.0


def test_a_second_run_in_the_same_domain_is_refused(tmp_path, ros_context):
    """Two graphs in one domain and namespace would answer each other's states."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import JointState

    from pkm_common.qos import STREAM_QOS
    other = rclpy.create_node("other_run", namespace="/pkm", context=ros_context)
    other.create_publisher(JointState, "drives/state", STREAM_QOS)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(other)
    try:
        run = run_scenario(load_scenario("mom3_square", SHORT), tmp_path / "second", in_process=True,
                           progress=False)
    finally:
        executor.shutdown()
        other.destroy_node()
    assert run["status"] == "failed" and "another run is active" in run["error"]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_that_surfaces_as_another_error_still_reads_interrupted(tmp_path, monkeypatch, sig):
    """A KeyboardInterrupt raised while rclpy's C++ executor converts a message for a
    callback reaches Python as pybind11's RuntimeError("Unable to convert call
    argument '0' to Python object"). The run was interrupted: run.json says so, not
    that the run failed on a RuntimeError; and the handlers are put back afterwards."""
    from pkm_bringup import orchestrator

    def interrupted_inside_a_callback(*_):
        try:
            signal.raise_signal(sig)
        except KeyboardInterrupt:
            raise RuntimeError("Unable to convert call argument '0' to Python object") from None
    monkeypatch.setattr(orchestrator, "run_processes", interrupted_inside_a_callback)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    run = run_scenario(load_scenario("archi_demo", {"record": False}), tmp_path / "run", progress=False)
    assert run["status"] == "failed" and run["error"] == "interrupted (Ctrl-C / SIGTERM)", run["error"]
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before

    def failing(*_):
        raise RuntimeError("a real defect")
    monkeypatch.setattr(orchestrator, "run_processes", failing)
    run = run_scenario(load_scenario("archi_demo", {"record": False}), tmp_path / "run2", progress=False)
    assert run["error"] == "RuntimeError: a real defect"


def _dds_participant_threads() -> int:
    """Fast DDS's event threads of this process (one per participant: 'dds.ev.<n>')."""
    names = (Path(f"/proc/self/task/{t}/comm").read_text().strip() for t in os.listdir("/proc/self/task"))
    return sum(name.startswith("dds.ev.") for name in names)


def test_an_in_process_run_leaves_no_dds_participant_behind(tmp_path):
    """A run's DDS participant ends with the run: left to the garbage collector, it
    lived on into the next run of the process (a gallery, a study, a test worker) and
    met the next run's participant."""
    import gc
    gc.collect()                       # what earlier tests of this worker left to the collector
    before = _dds_participant_threads()
    run = run_scenario(load_scenario("mom3_square", {"duration_s": 0.05, "record": False}), tmp_path / "run",
                       in_process=True, progress=False, report=False)
    assert run["status"] == "completed", run["error"]
    assert _dds_participant_threads() == before


def test_a_node_that_died_is_the_runs_cause_unless_the_machine_stopped_first():
    from pkm_bringup.graph import node_died
    from pkm_bringup.orchestrator import run_cause
    from pkm_common.causes import TripCause
    failed = node_died("sim_hw", -9, "last words")
    assert failed.cause == TripCause.NODE_DIED
    assert str(failed).startswith("node sim_hw exited with code -9 (killed by SIGKILL); its last output")
    why = "node sim_hw exited with code -9 (killed by SIGKILL)"
    silent = {"controller": {"stopped": True, "cause": "watchdog", "stop_reason": "drives/state silent"}}
    tripped = {"controller": {"stopped": True, "cause": "following_error", "stop_reason": "12 mm"}}
    for summaries in ({}, silent):                   # no stop, or its consequence: the death started it
        assert run_cause(summaries, failed.cause, str(failed)) == (TripCause.NODE_DIED, why)
    assert run_cause(tripped, failed.cause, str(failed)) == (TripCause.FOLLOWING_ERROR, "12 mm")
    assert run_cause(silent) == (TripCause.WATCHDOG, "drives/state silent")
    assert "killed by signal 99" in str(node_died("x", -99, ""))


@pytest.fixture
def small_disk(tmp_path):
    """A filesystem of a few megabytes (tmpfs; root, as CI and this project's machines
    are): ``small_disk(size)`` mounts one and returns its path; unmounted after."""
    mounted = []

    def mount(size: str) -> Path:
        path = tmp_path / f"disk{len(mounted)}"
        path.mkdir()
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                              capture_output=True, text=True)
        if done.returncode != 0:
            pytest.skip(f"a small filesystem needs mount (root): {done.stderr.strip()}")
        mounted.append(path)
        return path
    yield mount
    for path in mounted:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


@pytest.mark.slow
def test_a_disk_that_fills_up_ends_the_run_with_its_cause_and_a_whole_run_json(small_disk):
    """On a 4 MB disk the bag fills it mid-run: the recorder dies; the run is named
    failed by node_died "the disk is full", exit 1, its run.json and the nodes'
    summaries whole (the space kept for them at the start), the bag readable. Before,
    pkm-run ended in a traceback writing run.json and left it and the summaries empty."""
    run_dir = small_disk("4m") / "run"
    proc = _pkm_run("archi_demo", "--run-dir", str(run_dir))
    out, _ = proc.communicate(timeout=180)
    assert proc.returncode == 1, out[-3000:]
    assert out.rstrip().splitlines()[-1].startswith("  run directory:"), out[-3000:]    # its summary, no traceback
    run = json.loads((run_dir / "run.json").read_text())
    assert run["status"] == "failed" and run["cause"] == "node_died", (run["status"], run["cause"])
    assert run["trip_reason"] == "node recorder exited with code 1: the disk is full", run["trip_reason"]
    for name in ("sim_hw", "controller", "gough_sensor", "recorder"):
        assert json.loads((run_dir / "summaries" / f"{name}.json").read_text()), name
    assert run["recovered"]["messages"] > 1000                  # the bag, readable up to its last chunk
    assert not list(run_dir.glob(".reserved*")) and not _leftovers(run_dir)


@pytest.mark.slow
def test_a_disk_too_full_for_the_end_of_a_run_refuses_it_before_anything_starts(small_disk):
    run_dir = small_disk("1m") / "run"
    proc = _pkm_run("archi_demo", "--run-dir", str(run_dir))
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 1, out[-3000:]
    run = json.loads((run_dir / "run.json").read_text())
    assert run["status"] == "failed" and "nothing started" in run["error"] and "No space left" in run["error"], run
    assert not list(run_dir.glob(".reserved*"))
    assert not (run_dir / "bag").exists() and not list((run_dir / "logs").iterdir())    # no node was started


def test_run_json_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """run_files.write_json: a disk full in the middle of the write leaves the old file
    as it was and no temporary file."""
    import errno

    from pkm_common import files
    path = tmp_path / "run.json"
    files.write_json(path, {"status": "completed"})

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(files.json, "dump", full)
    with pytest.raises(OSError):
        files.write_json(path, {"status": "failed"})
    assert json.loads(path.read_text()) == {"status": "completed"} and sorted(tmp_path.iterdir()) == [path]
    assert files.disk_full(OSError(errno.ENOSPC, "full")) and not files.disk_full(OSError(errno.EIO, "io"))
    # a node's summary on a full disk: logged, never raised into the node's end
    errors = []
    assert files.write_summary(tmp_path / "new.json", {"x": 1}, errors.append) is False and "No space" in errors[0]
    # ... or written into the blocks it reserved at start, which a full disk cannot take
    monkeypatch.undo()
    summary = tmp_path / "sim_hw.json"
    assert files.reserve_file(summary, 4096) and summary.stat().st_size == 4096 and not files.summary_written(summary)
    assert files.write_summary(summary, {"steps": 3}, errors.append) and json.loads(summary.read_text()) == {"steps": 3}


def test_files_of_a_scratch_directory_are_whole_but_not_forced_to_the_disk(tmp_path, monkeypatch):
    """files.scratch (a study's run directory, read once then removed): JSON and
    summaries still whole (renamed into place), no fsync, no space set aside; outside
    it, each write is forced to the disk again."""
    from pkm_common import files
    synced = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(fd) or real_fsync(fd))

    def write_all(where: Path) -> None:
        where.mkdir()
        files.write_json(where / "run.json", {"status": "completed"})
        files.reserve_file(where / "sim_hw.json", 4096)
        files.write_summary(where / "sim_hw.json", {"steps": 3}, print)
    from pkm_common.cdr import encode_clock
    from pkm_recording.bag import BagWriter

    def write_bag(where: Path) -> None:
        writer = BagWriter(where, compression="none")
        clock = writer.add_topic("/clock", "rosgraph_msgs/msg/Clock")
        writer.write(clock, 1, encode_clock(1))
        writer.close()
    files.reserve_file(tmp_path / "reserved.json", 4096)      # reserved before, written inside
    with files.scratch():
        assert not files.durable()
        write_all(tmp_path / "scratch")
        assert not files.reserve_file(tmp_path / "scratch" / "other.json")
        files.write_summary(tmp_path / "reserved.json", {"steps": 1}, print)
        write_bag(tmp_path / "scratch" / "bag")                # a failed run's messages, kept as its bag
    assert synced == [] and files.durable(), synced
    assert json.loads((tmp_path / "reserved.json").read_text()) == {"steps": 1}
    assert (tmp_path / "scratch" / "bag" / "metadata.yaml").is_file()
    assert sorted(p.name for p in (tmp_path / "scratch").iterdir()) == ["bag", "run.json", "sim_hw.json"]
    assert json.loads((tmp_path / "scratch" / "sim_hw.json").read_text()) == {"steps": 3}
    write_all(tmp_path / "kept")
    assert len(synced) == 2, synced        # run.json; the summary written into its reserved blocks
    write_bag(tmp_path / "kept" / "bag")
    assert len(synced) >= 4, synced        # the bag's file, then its metadata.yaml
