"""``pkm-run``: run a scenario end to end — every node, recording, summary, report.

Multi-process (default): recorder, sim_hw, gough_sensor, controller as processes
(processes.py), parameters from the scenario (scenario.py) written to
``<run_dir>/params/<node>.yaml``. The run starts only when the graph is connected
(every stream of the scenario has its publisher and subscriber, the recorder is
subscribed to all of them); then trajectory_node is started, the controller (told to
wait for its trajectory) answers the first state and the lockstep begins; without a
program the controller starts at a start signal, and in realtime mode trajectory_node
runs all the same, for the goals and programs of an operator (pkm-panel). The run ends
when sim_hw reaches ``duration_s``; the nodes are then stopped in order, the recorder
last. A node that exits early is a crash: reported with its last output, everything
else stopped. Ctrl-C / SIGTERM stop everything the same way (the bag is finalized).

In-process (``--in-process``): the same nodes and parameters in one executor, for fast
tests; in lockstep both modes compute the same run (tests/bringup).

Realtime profile (``--rt-profile``, or the scenario's ``realtime_profile: true``):
SCHED_FIFO and locked memory for the loop's nodes (rt_profile.py), set as each
process starts; in one process, for the whole process during the run. Refused (exit
2, nothing started) where the OS does not allow it.

Every command that can move the machine carries the run's credential (pkm_common.credential):
pkm-run makes a key per run (``credential.key``, mode 600) or takes one (``--credential``:
a panel's, a script's), gives its path to the nodes, and signs its start signal.

Run directory::

    runs/<date>-<time>_<scenario>/
      credential.key  scenario.yaml  params/<node>.yaml  logs/<node>.log  summaries/<node>.json
      bag/ (rosbag2: metadata.yaml + .mcap)  run.json  report/ (metrics.json, *.png)

Why over 600 lines: one run's life from the scenario to run.json (set-up, the graph as
processes or in one executor, start, progress, the end and its summaries) shares its
state across those steps; the in-process executor is the first part to move out.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from pkm_bringup.scenario import (START_TOPIC, Scenario, ScenarioError, controller_node_name, expected_topics,
                                  load_scenario, node_parameters, params_file_text)
from pkm_bringup.run_files import DiskReserve
from pkm_common import topics
from pkm_common.causes import TripCause, parse_cause, run_status
from pkm_common.credential import KEY_FILE, RunKey
from pkm_common.files import disk_full, summary_written, write_json
from pkm_controller.strategies import REGISTRY as STRATEGIES

# start order; the stop order is the reverse of the run order with the recorder last
START_ORDER = ("recorder", "sim_hw", "gough_sensor", "controller")
# after the sim's last step, how long the loop's nodes keep running (see run_processes)
LOOP_END_GRACE_S = 0.15
STOP_ORDER = ("trajectory", "starter", "controller", "gough_sensor", "sim_hw", "recorder")
CONNECT_TIMEOUT_S = 60.0
DRAIN_S = 0.5
DRAIN_IN_PROCESS_S = 0.2


# pkm-run's exit code per run status (2: the scenario or the arguments were refused)
EXIT_CODES = {"completed": 0, "failed": 1, "tripped": 3}


class RunFailed(RuntimeError):
    """The run could not complete (crash, timeout, no connection); the message says why,
    ``cause`` what started it when it is the machine's (a node that died: NODE_DIED)."""

    def __init__(self, message: str, cause: TripCause = TripCause.NONE):
        super().__init__(message)
        self.cause = cause


def node_died(name: str, code: int, tail: str) -> RunFailed:
    """A node's process ended unbidden: its exit code, the signal that killed it, its last output."""
    how = ""
    if code < 0:
        try:
            how = f" (killed by {signal.Signals(-code).name})"
        except ValueError:
            how = f" (killed by signal {-code})"
    if "No space left on device" in tail or "Disk quota exceeded" in tail:
        how += ": the disk is full"
    return RunFailed(f"node {name} exited with code {code}{how}; its last output:\n{tail}", TripCause.NODE_DIED)


def run_cause(summaries: dict, failure: TripCause = TripCause.NONE, error: str = "") -> tuple[TripCause, str]:
    """The cause that started the run's stop and its reason (trip_cause), but a node
    that died (``failure``) when the machine did not stop before, or stopped only as a
    consequence: its inputs went silent (watchdog), its plant braked."""
    cause, reason = trip_cause(summaries)
    if failure != TripCause.NONE and cause in (TripCause.NONE, TripCause.WATCHDOG, TripCause.PLANT_SAFE_STOP):
        return failure, error.split("; its last output")[0]
    return cause, reason


def make_run_dir(s: Scenario, root: Path) -> Path:
    run_dir = root / f"{time.strftime('%Y%m%d-%H%M%S')}_{s.name}"
    suffix = 1
    while run_dir.exists():
        suffix += 1
        run_dir = root / f"{time.strftime('%Y%m%d-%H%M%S')}_{s.name}_{suffix}"
    return run_dir


class Progress:
    def __init__(self, total_s: float, stream=sys.stderr, enabled: bool = True):
        self.total, self.stream, self.enabled = total_s, stream, enabled
        self.tty = enabled and hasattr(stream, "isatty") and stream.isatty()
        self.shown = -1

    def update(self, t_s: float) -> None:
        if not self.enabled:
            return
        frac = min(max(t_s / self.total, 0.0), 1.0) if self.total > 0 else 0.0
        pct = int(frac * 100)
        if self.tty:
            bar = "#" * (pct // 4) + "-" * (25 - pct // 4)
            self.stream.write(f"\r[{bar}] {pct:3d}%  t = {t_s:7.3f} / {self.total:.3f} s")
            self.stream.flush()
        elif pct // 10 > self.shown:
            self.shown = pct // 10
            self.stream.write(f"  {pct:3d}%  t = {t_s:.3f} / {self.total:.3f} s\n")
            self.stream.flush()

    def done(self) -> None:
        if self.tty:
            self.stream.write("\n")


def end_context(context) -> None:
    """Shut ``context`` down, destroy it and collect what held it: its DDS participant
    (threads, sockets) goes with the run. Shut down only, it lived on until a garbage
    collection, in a process of many runs (a gallery, a study, a test worker) the one
    at the next run's start, after the next run's participant had met it. That overlap
    is the likely cause of a suite's in-process run whose plant refused "a second
    /pkm/controller" on drives/command at its first command (not reproduced in 17
    runs of the same pair of experiments)."""
    import gc

    import rclpy
    rclpy.try_shutdown(context=context)
    context.destroy()
    gc.collect()


def _monitor(context, namespace: str):
    """A small node of the orchestrator: simulated time (progress), the end of the
    loop and graph checks. It follows the sim's diagnostics (1 Hz and a last one when
    it finishes) and the controller's status (every 100 answers), never a per-step
    stream: one more reader of /clock cost the loop 5-15 % (measured)."""
    from rclpy.node import Node

    from pkm_common.endpoints import subscription
    node = Node("bringup_monitor", namespace=namespace, context=context)
    node.sim_time_s = 0.0
    node.sim_finished = False
    node.controller_stopped = False

    def on_diagnostics(msg):
        for status in msg.status:
            if status.name == "sim_hw":
                values = {kv.key: kv.value for kv in status.values}
                node.sim_finished = node.sim_finished or values.get("finished") == "True"
                on_time(msg)

    def on_time(msg):
        node.sim_time_s = max(node.sim_time_s, msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)

    def on_status(msg):                 # a safe stop publishes its status at once
        on_time(msg)
        node.controller_stopped = node.controller_stopped or any(
            kv.key == "mode" and kv.value == "stopped" for status in msg.status for kv in status.values)
    subscription(node, topics.DIAGNOSTICS, on_diagnostics)
    subscription(node, topics.CONTROLLER_STATUS, on_status)
    return node


def _estop_before_stop(executor, monitor, nodes: dict, wait_s: float = 1.0) -> None:
    """An interrupted run stops the machine before its processes, as the panel's E-stop
    does: the controller brakes the plant and names the stop (cause estop). Stopped
    first, the controller would leave a realtime plant to its watchdog, and the run would
    name that consequence ("watchdog") as its cause. Waits up to ``wait_s`` for the
    controller's stopped status. Whatever fails here, the ordered stop that follows runs."""
    from std_msgs.msg import Bool
    controller = nodes.get("controller")
    if controller is None or not controller.running() or monitor.controller_stopped:
        return
    try:
        monitor.estop_publisher.publish(Bool(data=True))
        end = time.monotonic() + wait_s
        while time.monotonic() < end and not monitor.controller_stopped:
            executor.spin_once(timeout_sec=0.02)
    except Exception as exc:              # noqa: BLE001 - the processes must still be stopped in order
        print(f"pkm-run: the E-stop before the stop failed: {type(exc).__name__}: {exc}", file=sys.stderr)


def init_context():
    """An rclpy context without rclpy's signal handlers: Ctrl-C / SIGTERM stay Python's
    KeyboardInterrupt, so the ordered stop always runs (rclpy's handlers shut the
    context down under a running spin_once)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    context = rclpy.Context()
    rclpy.init(context=context, args=[], signal_handler_options=SignalHandlerOptions.NO)
    return context


LOCK_DIR = Path(os.environ.get("PKM_RUN_LOCK_DIR", "/tmp/pkm-run-locks"))


class RunLock:
    """One run per DDS domain and namespace on this machine: an exclusive ``flock`` on
    ``LOCK_DIR/domain-<id><namespace>.lock``, held for the run and released by the
    kernel when the process ends (however it ends). Discovery is kept on localhost,
    so this covers every run that could cross-talk, without waiting for discovery."""

    def __init__(self, namespace: str):
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        self.path = LOCK_DIR / f"domain-{domain}{namespace.replace('/', '_')}.lock"
        self.domain, self.namespace, self.fh = domain, namespace, None

    def __enter__(self):
        import fcntl
        LOCK_DIR.mkdir(parents=True, exist_ok=True)
        self.fh = open(self.path, "a+", encoding="utf-8")
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.fh.seek(0)
            holder = self.fh.read().strip() or "another process"
            self.fh.close()
            raise RunFailed(f"another run is active in ROS_DOMAIN_ID={self.domain}, namespace {self.namespace} "
                            f"({holder}); use another domain (export ROS_DOMAIN_ID=...) or namespace") from None
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(f"pid {os.getpid()}")
        self.fh.flush()
        return self

    def __exit__(self, *exc):
        self.fh.close()                       # closing releases the lock


def _refuse_if_another_run(executor, monitor, s: Scenario, discovery_s: float = 1.0) -> None:
    """Two runs in one DDS domain and namespace would answer each other's states. Runs of
    this machine are refused by RunLock at once; this looks for any other (a graph
    started by hand) for ``discovery_s``."""
    end = time.monotonic() + discovery_s
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    for topic in ("/clock", s.topic("drives/state")):
        if monitor.count_publishers(topic):
            raise RunFailed(f"another run is active: {topic} already has a publisher in ROS_DOMAIN_ID="
                            f"{os.environ.get('ROS_DOMAIN_ID', '0')}; use another domain (export ROS_DOMAIN_ID=...)")


def _publish_start(node, credential: Path) -> None:
    """The latched start signal of a scenario without a program (controller
    wait_for_start), with the run's credential (pkm_common.credential)."""
    from pkm_common.credential import RunKey, Signer
    from pkm_common.endpoints import publisher
    node.start_publisher = publisher(node, START_TOPIC)
    signer = Signer(RunKey.read(credential), node.get_fully_qualified_name())
    node.start_publisher.publish(signer.text(START_TOPIC, "start"))


def _refuse_intruders(monitor, s: Scenario) -> None:
    """Only the run's controller may publish drives/command (sim_hw stops on any other:
    refused here before the run starts, naming the node)."""
    from pkm_common.conversions import publisher_names
    topic = s.topic("drives/command")
    names = publisher_names(monitor.get_publishers_info_by_topic(topic))
    others = sorted(set(names) - {controller_node_name(s)})
    if names.count(controller_node_name(s)) > 1:          # an orphan of an earlier run, of the same name
        others.append(f"a second {controller_node_name(s)}")
    if others:
        raise RunFailed(f"intruder: {', '.join(others)} publishes on {topic}, where only {controller_node_name(s)} "
                        "may; stop it or use another domain")


def _connected(monitor, s: Scenario) -> bool:
    """Every stream has its publisher; every edge of the loop its subscriber too."""
    edges = ["drives/state", "drives/command"]
    if s.metrology:
        edges.append("platform/true_pose")
    topic = STRATEGIES[s.strategy].metrology_topic
    if topic:
        edges.append(topic)
    for topic in expected_topics(s):
        name = s.topic(topic)
        if monitor.count_publishers(name) < 1 or (topic in edges and monitor.count_subscribers(name) < 1):
            return False
    return True


def _scheduling(s: Scenario, node: str):
    """The realtime profile's scheduling of ``node`` when the scenario asks for it."""
    from pkm_bringup.rt_profile import scheduling
    return scheduling(node) if s.realtime_profile else None


def _in_process_profile(s: Scenario, in_process: bool):
    """One process with the realtime profile: the whole orchestrator at the loop's
    priority with its memory locked for the run (the recorder, on the loop's thread,
    with it), then as before; a no-op otherwise."""
    if not (in_process and s.realtime_profile):
        return contextlib.nullcontext()
    from pkm_bringup.rt_profile import applied_to_this_process
    return applied_to_this_process()


def run_processes(s: Scenario, run_dir: Path, params: dict, progress: Progress, codes: dict,
                  interruption=None, reserve=None) -> dict:
    """The scenario as separate processes; fills and returns ``codes`` (exit codes).
    Raises RunFailed. ``interruption``: the run's _Interruption (signalled: an E-stop
    before the ordered stop)."""
    from pkm_bringup.processes import start_node, stop_nodes
    context = init_context()
    from rclpy.experimental import EventsExecutor
    executor = EventsExecutor(context=context)
    monitor = _monitor(context, s.namespace)
    executor.add_node(monitor)
    from pkm_common.endpoints import publisher
    # matched with the controller from the start: an interrupt's E-stop goes out at once
    monitor.estop_publisher = publisher(monitor, topics.ESTOP)
    nodes = {}

    def check_alive(allowed_done=()):
        for node in nodes.values():
            if not node.running() and node.name not in allowed_done:
                raise node_died(node.name, node.popen.returncode, node.tail())
    try:
        _refuse_if_another_run(executor, monitor, s)
        # a planner for an operator (realtime, no program) starts with the loop's nodes and
        # is up before the start: its start-up (imports, ~1 s of CPU) stalled a running loop
        operator_planner = "trajectory" in params and s.program is None
        for name in START_ORDER + (("trajectory",) if operator_planner else ()):
            if name in params:
                nodes[name] = start_node(name, s.namespace, run_dir / "params" / f"{name}.yaml",
                                         run_dir / "logs", os.environ.copy(), _scheduling(s, name))
        ready = run_dir / "recorder.ready"
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        while not (_connected(monitor, s) and (not s.record or ready.exists()) and
                   (not operator_planner or monitor.count_publishers(s.topic("trajectory")) > 0)):
            check_alive()
            _refuse_intruders(monitor, s)
            if time.monotonic() > deadline:
                raise RunFailed(f"graph not connected within {CONNECT_TIMEOUT_S:g} s (see {run_dir / 'logs'})")
            executor.spin_once(timeout_sec=0.05)
        if "trajectory" in params and not operator_planner:   # the run starts when the controller has its trajectory
            nodes["trajectory"] = start_node("trajectory", s.namespace, run_dir / "params" / "trajectory.yaml",
                                             run_dir / "logs", os.environ.copy(), _scheduling(s, "trajectory"))
        if s.program is None:               # ... or at the start signal (realtime: the planner waits for goals)
            _publish_start(monitor, Path(params["controller"]["credential_file"]))
        deadline = time.monotonic() + s.timeout_s
        sim = nodes["sim_hw"]
        # the loop is over when the sim has exited, or LOOP_END_GRACE_S after it finished
        # (its last diagnostics, or its summary file, written before it shuts down: the
        # exit of a process with compiled kernels takes ~0.4 s, close to the
        # controller's state watchdog; the grace lets the last state be answered)
        sim_summary = run_dir / "summaries" / "sim_hw.json"
        finished_wall = math.inf
        while sim.running() and time.monotonic() < finished_wall + LOOP_END_GRACE_S:
            check_alive(allowed_done=("sim_hw",))
            if time.monotonic() > deadline:
                raise RunFailed(f"timeout_s: the run did not end within {s.timeout_s:g} s (wall clock)")
            executor.spin_once(timeout_sec=0.02)
            progress.update(monitor.sim_time_s)
            if finished_wall == math.inf and (monitor.sim_finished or summary_written(sim_summary)):
                finished_wall = time.monotonic()
        progress.update(s.duration_s)
        if "recorder" in nodes:       # the loop is over: its idle priority would starve the last batches
            from pkm_recording.recording import normal_cpu_priority
            normal_cpu_priority(nodes["recorder"].popen.pid)
        # stop the loop's nodes at once (their watchdogs would report the silent
        # plant), then give the recorder time for the last messages
        codes.update(stop_nodes([nodes[n] for n in STOP_ORDER if n in nodes and n not in ("recorder", "sim_hw")],
                                together=True))
        with contextlib.suppress(subprocess.TimeoutExpired):     # the sim ends by itself
            sim.popen.wait(timeout=10.0)
        if sim.popen.returncode is None:
            raise RunFailed(f"node sim_hw finished but did not exit within 10 s; its last output:\n{sim.tail()}")
        if sim.popen.returncode != 0:
            raise node_died("sim_hw", sim.popen.returncode, sim.tail())
        end = time.monotonic() + DRAIN_S
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    finally:
        progress.done()
        if reserve is not None:               # the nodes' summaries and run.json get the space kept for them
            reserve.release()
        with _signals_ignored():              # a second Ctrl-C must not abandon the ordered stop
            if interruption is not None and interruption.signalled:
                _estop_before_stop(executor, monitor, nodes)
            codes.update(stop_nodes([nodes[n] for n in STOP_ORDER if n in nodes]))
        executor.shutdown()
        monitor.destroy_node()
        end_context(context)
    return codes


def run_in_process(s: Scenario, run_dir: Path, params: dict, progress: Progress, codes: dict,
                   interruption=None, reserve=None) -> dict:
    """The scenario with every node in one EventsExecutor (same parameters); an
    interruption stops every node at once (no plant runs on without its controller)."""
    from rclpy.experimental import EventsExecutor
    from rclpy.parameter import Parameter

    from pkm_recording.recorder_node import RecorderNode
    from pkm_common.runner import start_up_frozen
    from pkm_controller.controller_node import ControllerNode
    from pkm_gough_sensor.gough_sensor_node import GoughSensorNode
    from pkm_sim_hw.sim_hw_node import SimHwNode
    from pkm_trajectory.trajectory_node import TrajectoryNode
    classes = {"recorder": RecorderNode, "sim_hw": SimHwNode, "gough_sensor": GoughSensorNode,
               "controller": ControllerNode, "trajectory": TrajectoryNode}
    context = init_context()
    executor = EventsExecutor(context=context)
    nodes = {}

    def create(name):
        values = dict(params[name])
        if name == "sim_hw":
            values["shutdown_on_finish"] = False
        if name == "recorder":
            values["cpu_priority"] = "normal"     # idle would demote the whole loop with it
        overrides = [Parameter(k, value=v) for k, v in values.items()]
        try:
            nodes[name] = classes[name](context=context, namespace=s.namespace, parameter_overrides=overrides)
        except Exception as exc:                  # noqa: BLE001 - a refused configuration is the run's failure
            raise RunFailed(f"node {name} refused its configuration: {exc}") from None
        executor.add_node(nodes[name])
        tap = getattr(nodes[name], "tap", None)
        if "recorder" in nodes and tap is not None and tap.tap is not None:
            tap.sink = nodes["recorder"].write_records    # one process: no batch messages

    def close(names):
        for name in names:
            node = nodes.pop(name, None)
            if node is not None:
                executor.remove_node(node)
                node.destroy_node()
    try:
        monitor = _monitor(context, s.namespace)
        executor.add_node(monitor)
        _refuse_if_another_run(executor, monitor, s, discovery_s=0.5)
        executor.remove_node(monitor)
        monitor.destroy_node()
        for name in START_ORDER:
            if name in params:
                create(name)
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        while s.record and not nodes["recorder"].ready:
            if time.monotonic() > deadline:
                raise RunFailed(f"recorder not ready within {CONNECT_TIMEOUT_S:g} s")
            executor.spin_once(timeout_sec=0.05)
        if "trajectory" in params:
            create("trajectory")
        if s.program is None:
            starter = _monitor(context, s.namespace)
            executor.add_node(starter)
            nodes["starter"] = starter
            _publish_start(starter, Path(params["controller"]["credential_file"]))
        deadline = time.monotonic() + s.timeout_s
        sim = nodes["sim_hw"]
        last = 0.0
        with start_up_frozen():
            while not sim.finished:
                if time.monotonic() > deadline:
                    raise RunFailed(f"timeout_s: the run did not end within {s.timeout_s:g} s (wall clock)")
                executor.spin_once(timeout_sec=0.05)
                if time.monotonic() - last > 0.1:
                    last = time.monotonic()
                    progress.update(sim.plant.t)
        progress.update(s.duration_s)
        # no node may be destroyed while the executor still runs (a queued callback would
        # publish on it); the drain is shorter than the controller's state watchdog
        end = time.monotonic() + DRAIN_IN_PROCESS_S
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    finally:
        progress.done()
        if reserve is not None:
            reserve.release()
        with _signals_ignored():
            close(STOP_ORDER)
        executor.shutdown()
        end_context(context)
    codes.update({name: 0 for name in params})
    return codes


class _stop_signals:
    """SIGINT and SIGTERM handled by ``handler`` inside the block, the handlers before
    put back after it (main thread only; elsewhere nothing changes)."""

    def __init__(self, handler):
        self.handler = handler

    def __enter__(self):
        import threading
        self.saved = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.saved[sig] = signal.signal(sig, self.handler)
        return self

    def __exit__(self, *exc):
        for sig, handler in self.saved.items():
            signal.signal(sig, handler)


def _signals_ignored() -> _stop_signals:
    """SIGINT/SIGTERM ignored inside the block (main thread only)."""
    return _stop_signals(signal.SIG_IGN)


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def trip_cause(summaries: dict) -> tuple[TripCause, str]:
    """The cause that started the run's stop, and its reason: the controller's (it takes
    the plant's when the plant braked first), else the plant's."""
    for node in ("controller", "sim_hw"):
        summary = summaries.get(node, {})
        if summary.get("stopped"):
            try:
                cause = parse_cause(summary.get("cause", "none"))
            except ValueError:
                continue
            if cause != TripCause.NONE:
                return cause, summary.get("stop_reason") or summary.get("message", "")
    return TripCause.NONE, ""


def collect(s: Scenario, run_dir: Path, mode: str, wall_s: float, codes: dict, error: str = "",
            failure: TripCause = TripCause.NONE) -> dict:
    """run.json: node summaries, published vs recorded per topic, exit codes; ``failure``:
    the cause of the RunFailed that ended it (run_cause)."""
    summaries = {p.stem: _read_json(p) for p in sorted((run_dir / "summaries").glob("*.json"))}
    published = {}
    for node in ("sim_hw", "controller", "gough_sensor"):
        for topic, count in summaries.get(node, {}).get("published", {}).items():
            published[s.topic(topic)] = count
    recorded = summaries.get("recorder", {}).get("recorded_stamps", {})
    lost = {t: n - recorded.get(t, 0) for t, n in published.items()} if s.record else {}
    if any(v < 0 for v in lost.values()) and not error:
        error = (f"more messages recorded than published on {[t for t, v in lost.items() if v < 0]}: "
                 "another graph publishes in this domain and namespace")
    cause, reason = run_cause(summaries, failure, error)
    # DDS delivery to the sensor is not a recording loss, but a true pose it never
    # measured is a step the metrology missed: stated, not silent
    sensor, sim = summaries.get("gough_sensor", {}), summaries.get("sim_hw", {})
    sensor_missed = max(0, sim.get("published", {}).get("platform/true_pose", 0)
                        - sensor.get("published", {}).get("metrology/struts", 0)) if sensor and sim else 0
    run = {"scenario": s.name, "machine": s.machine, "namespace": s.namespace, "mode": mode,
           "strategy": s.strategy, "distribution": s.controller.get("distribution"),
           "metrology": s.metrology, "realtime_profile": s.realtime_profile, "duration_s": s.duration_s,
           "wall_s": wall_s,
           "status": run_status(error, cause), "error": error, "cause": str(cause), "trip_reason": reason,
           "sensor_missed_steps": sensor_missed, "exit_codes": codes,
           "published": published, "recorded": recorded, "lost": lost, "summaries": summaries}
    _write_run(run_dir, run)
    return run


def _write_run(run_dir: Path, run: dict) -> None:
    """run.json, whole (run_files.write_json); a disk too full even for it is said on
    stderr and in the returned record, never a traceback."""
    try:
        write_json(run_dir / "run.json", run)
    except OSError as exc:
        run["status"], run["error"] = "failed", run.get("error") or f"run.json not written: {exc}"
        print(f"pkm-run: run.json not written: {exc}", file=sys.stderr)


def run_scenario(s: Scenario, run_dir: Path, in_process: bool = False, progress: bool = True,
                 report: bool = True, credential: Path | None = None) -> dict:
    """Run ``s`` into ``run_dir`` (created); returns run.json's content (status
    ``completed`` or ``failed`` with ``error``), with ``metrics`` when recorded.
    ``credential``: the key file the run's commands are signed with (a panel's, a
    script's: pkm_common.credential); by default a new one in the run directory.
    Raises rt_profile.RealtimeProfileRefused, before anything is made or started,
    when the scenario asks for the realtime profile and the OS does not allow it."""
    if s.realtime_profile:
        from pkm_bringup.rt_profile import check_permitted
        check_permitted(in_process)
    mode = "in_process" if in_process else "processes"
    reserves = []
    try:                                       # nothing started yet: a full disk is said, not a traceback
        for sub in ("params", "logs", "summaries"):
            (run_dir / sub).mkdir(parents=True, exist_ok=True)
        # the end of the run's space, kept from the start: the nodes' summaries, then run.json
        reserves = [DiskReserve(run_dir, "nodes"), DiskReserve(run_dir, "end")]
        for reserve in reserves:
            if not reserve.held:
                raise OSError(reserve.error)
        for stale in (run_dir / "summaries").glob("*.json"):     # a run directory used again
            stale.unlink()
        if credential is None:
            RunKey.create(run_dir / KEY_FILE)
        params = node_parameters(s, run_dir, credential)
        for name, values in params.items():
            (run_dir / "params" / f"{name}.yaml").write_text(params_file_text(values), encoding="utf-8")
        (run_dir / "scenario.yaml").write_text(s.source.read_text(encoding="utf-8"), encoding="utf-8")
        if credential is not None:
            RunKey.read(credential)                # a key others may read, or none: said before anything starts
    except BaseException as exc:
        for reserve in reserves:
            reserve.release()
        if isinstance(exc, ValueError):
            return collect(s, run_dir, mode, 0.0, {}, f"{exc}; nothing started")
        if not isinstance(exc, OSError):
            raise
        return collect(s, run_dir, mode, 0.0, {}, f"the run directory cannot be written, nothing started: {exc}")
    from pkm_bringup.processes import use_ros_environment
    use_ros_environment()
    start = time.monotonic()
    error, codes, interruption, failure = "", {}, _Interruption(), TripCause.NONE
    try:
        run = run_in_process if in_process else run_processes
        with interruption, RunLock(s.namespace), _in_process_profile(s, in_process):
            run(s, run_dir, params, Progress(s.duration_s, enabled=progress), codes, interruption, reserves[0])
    except RunFailed as exc:
        error, failure = str(exc), exc.cause
    except KeyboardInterrupt:
        error = INTERRUPTED
    except Exception as exc:                      # noqa: BLE001 - reported in run.json, never a traceback
        # a signal's KeyboardInterrupt raised while rclpy's executor converts a message
        # for a callback comes out of pybind11 as RuntimeError("Unable to convert call
        # argument ..."): the run was interrupted all the same
        error = INTERRUPTED if interruption.signalled else f"{type(exc).__name__}: {exc}"
    for reserve in reserves:                       # (the first: a runner that failed before its loop)
        reserve.release()
    recovered = _recover_bag(s, run_dir)
    result = collect(s, run_dir, mode, time.monotonic() - start, codes, error, failure)
    if recovered:
        result["recovered"] = recovered
        _write_run(run_dir, result)
    if report and s.record and (run_dir / "bag" / "metadata.yaml").exists():
        from pkm_runs.report import write_report
        try:
            result["metrics"] = write_report(run_dir)
        except (ValueError, OSError) as exc:      # an unreadable bag (IncompleteBagError, ...): said, no traceback
            result["report_error"] = str(exc)
            if disk_full(exc):                     # the run's record is incomplete: the run failed
                result["status"], result["error"] = "failed", result["error"] or f"report: the disk is full: {exc}"
                _write_run(run_dir, result)
    return result


def _recover_bag(s: Scenario, run_dir: Path) -> dict:
    """A bag whose recorder died (no metadata.yaml): made readable up to its last
    complete chunk (bag.recover); the recorder's summary then holds what was saved, so
    that run.json states the loss. {} when there was nothing to recover."""
    bag = run_dir / "bag"
    if not s.record or not bag.is_dir() or (bag / "metadata.yaml").exists() or not any(bag.glob("*.mcap")):
        return {}
    from pkm_recording.bag import recover
    from pkm_common.cdr import stamp_ns_of
    try:
        counts = recover(bag)
    except (OSError, ValueError) as exc:
        return {"error": f"bag could not be recovered: {exc}"}
    summary_path = run_dir / "summaries" / "recorder.json"
    if not _read_json(summary_path):          # the recorder was killed (its reserved file holds zeros): the bag's count
        from rosbags.highlevel import AnyReader
        last: dict[str, int] = {}
        steps: dict[str, int] = {}
        with AnyReader([bag]) as reader:         # new stamps per topic, as the recorder counts
            for connection, _, data in reader.messages():
                stamp = stamp_ns_of(data) if len(data) >= 12 else -1
                if last.get(connection.topic) != stamp:
                    last[connection.topic] = stamp
                    steps[connection.topic] = steps.get(connection.topic, 0) + 1
        write_json(summary_path, {"recorded_stamps": steps, "recovered": True})
    return {"messages": sum(counts.values()) if isinstance(counts, dict) else counts}


def format_summary(run: dict, run_dir: Path) -> str:
    sims = run["summaries"].get("sim_hw", {})
    ctrl = run["summaries"].get("controller", {})
    lines = [f"scenario {run['scenario']} ({run['machine']}, {run['strategy']}"
             f"{', ' + run['distribution'] if run.get('distribution') else ''}, {run['mode']}"
             f"{', realtime profile' if run.get('realtime_profile') else ''}): {run['status']}"]
    if run["error"]:
        lines.append(f"  error: {run['error']}")
    if run.get("cause", "none") != "none":
        lines.append(f"  stopped by {run['cause']}: {run.get('trip_reason', '')}")
    if run.get("sensor_missed_steps"):
        lines.append(f"  gough_sensor: {run['sensor_missed_steps']} true poses not measured")
    if run.get("recovered"):
        lines.append(f"  the recorder did not finish: bag recovered up to its last chunk ({run['recovered']})")
    if sims:
        rate = sims.get("steps_per_s")
        lines.append(f"  steps {sims.get('steps')}  sim {sims.get('sim_time_s', 0):.3f} s  wall {run['wall_s']:.1f} s"
                     f"  loop {rate:.0f} steps/s" if rate else f"  steps {sims.get('steps')}")
        if sims.get("stopped"):
            lines.append(f"  plant stopped: {sims.get('stop_reason')}")
    if ctrl:
        lines.append(f"  controller: {ctrl.get('message')}  compute p50 {ctrl.get('compute_us_p50', 0):.0f} us"
                     f"  p99 {ctrl.get('compute_us_p99', 0):.0f} us")
    if run.get("report_error"):
        lines.append(f"  no report: {run['report_error']}")
    if run.get("metrics"):
        from pkm_runs.report import summary
        lines.append("  " + summary(run["metrics"]).replace("\n", "\n  "))
    lines.append(f"  run directory: {run_dir}")
    return "\n".join(lines)


INTERRUPTED = "interrupted (Ctrl-C / SIGTERM)"


def _interrupt(*_):
    raise KeyboardInterrupt


class _Interruption(_stop_signals):
    """Ctrl-C and SIGTERM raise KeyboardInterrupt inside the block, as
    ``signalled`` records (main thread only; elsewhere the handlers stay as they are
    and nothing is recorded)."""

    signalled = False

    def __init__(self):
        super().__init__(self._raise)

    def _raise(self, *_):
        if self.signalled:                 # a second signal (a panel's SIGTERM after a Ctrl-C, ...):
            return                         # the ordered stop of the first one is running
        self.signalled = True
        raise KeyboardInterrupt


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-run", description=__doc__.split("\n\n")[0])
    parser.add_argument("scenario", help="scenario file, or the name of one in config/scenarios")
    parser.add_argument("--in-process", action="store_true", help="all nodes in one executor")
    parser.add_argument("--runs", default="runs", help="parent of the run directory (default: runs)")
    parser.add_argument("--run-dir", help="exact run directory (must not exist)")
    parser.add_argument("--no-record", action="store_true")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--rt-profile", action="store_true",
                        help="realtime profile: SCHED_FIFO and locked memory for the loop's nodes "
                             "(the scenario key realtime_profile; needs root or CAP_SYS_NICE and CAP_IPC_LOCK)")
    parser.add_argument("--credential", metavar="FILE",
                        help="the key the run's commands are signed with (mode 600; a panel's or a script's: "
                             "pkm_common.credential); default: a new one, RUN_DIR/credential.key")
    args = parser.parse_args(argv)
    overrides = {**({"record": False} if args.no_record else {}),
                 **({"realtime_profile": True} if args.rt_profile else {})}
    try:
        s = load_scenario(args.scenario, overrides)
    except ScenarioError as exc:
        print(f"pkm-run: {exc}", file=sys.stderr)
        return 2
    if s.realtime_profile:                  # refused before anything is made or started
        from pkm_bringup.rt_profile import RealtimeProfileRefused, check_permitted
        try:
            check_permitted(args.in_process)
        except RealtimeProfileRefused as exc:
            print(f"pkm-run: {exc}", file=sys.stderr)
            return 2
    run_dir = (Path(args.run_dir) if args.run_dir else make_run_dir(s, Path(args.runs))).resolve()
    if run_dir.exists() and any(run_dir.iterdir()):
        print(f"pkm-run: run directory {run_dir} exists and is not empty", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, _interrupt)
    from pkm_bringup.processes import use_ros_environment
    domain = use_ros_environment()["ROS_DOMAIN_ID"]     # this shell's, or one claimed: said, to join it
    print(f"running {s.name}: {s.description or s.machine} ({s.duration_s:.3f} s simulated, "
          f"ROS_DOMAIN_ID={domain})", flush=True)
    credential = Path(args.credential).resolve() if args.credential else None
    print(f"commands need the credential in {credential or run_dir / KEY_FILE}", flush=True)
    run = run_scenario(s, run_dir, in_process=args.in_process, progress=not args.no_progress,
                       credential=credential)
    print(format_summary(run, run_dir), flush=True)
    return EXIT_CODES[run["status"]]


if __name__ == "__main__":
    sys.exit(main())
