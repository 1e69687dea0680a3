"""The graph of a run, on rclpy (pkm-run's side of DDS): its context, a small monitor
node (simulated time, the loop's end, the controller's stop), the checks before a run
starts (another run in the domain, an intruder on drives/command, the graph
connected), the start signal, and the scenario's nodes as processes
(``run_processes``); ``in_process.run_in_process`` runs them in one executor instead.
orchestrator.py (pkm-run) sequences a run around them.
"""

from __future__ import annotations

import contextlib
import gc
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Bool

from pkm_bringup.composed_loop import COMPOSED
from pkm_bringup.processes import start_node, stop_nodes
from pkm_bringup.rt_profile import scheduling
from pkm_bringup.scenario import START_TOPIC, Scenario, controller_node_name, expected_topics, start_signal
from pkm_common import topics
from pkm_common.causes import TripCause
from pkm_common.conversions import publisher_names
from pkm_common.endpoints import publisher, subscription
from pkm_common.files import summary_written
from pkm_controller.strategies import REGISTRY as STRATEGIES
from pkm_recording.recording import normal_cpu_priority

# start order; the stop order is the reverse of the run order with the recorder last
START_ORDER = ("recorder", "virtual_drives", "ros2_control_sim", "sim_hw", "drives", "ros2_control", "gough_sensor",
               "laser_tracker", "controller")
# after the sim's last step, how long the loop's nodes keep running (see run_processes)
LOOP_END_GRACE_S = 0.15
STOP_ORDER = ("trajectory", "starter", "controller", "gough_sensor", "laser_tracker", "sim_hw", "loop", "drives",
              "ros2_control", "virtual_drives", "ros2_control_sim", "recorder")
# the graph's machine: simulated, or a drive interface (one of them); behind one, its simulated machine
MACHINE_NODES = ("sim_hw", "drives", "ros2_control")
BEHIND = ("virtual_drives", "ros2_control_sim")
CONNECT_TIMEOUT_S = 60.0
DRAIN_S = 0.5
DRAIN_IN_PROCESS_S = 0.2


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


def end_context(context) -> None:
    """Shut ``context`` down, destroy it and collect what held it: its DDS participant
    (threads, sockets) goes with the run. Shut down only, it lived on until a garbage
    collection, in a process of many runs (a gallery, a study, a test worker) the one
    at the next run's start, after the next run's participant had met it. That overlap
    is the likely cause of a suite's in-process run whose plant refused "a second
    /pkm/controller" on drives/command at its first command (not reproduced in 17
    runs of the same pair of experiments)."""

    rclpy.try_shutdown(context=context)
    context.destroy()
    gc.collect()


def monitor_node(context, namespace: str):
    """A small node of the orchestrator: simulated time (progress), the end of the
    loop and graph checks. It follows the sim's diagnostics (1 Hz and a last one when
    it finishes) and the controller's status (every 100 answers), never a per-step
    stream: one more reader of /clock cost the loop 5-15 % (measured)."""

    node = Node("bringup_monitor", namespace=namespace, context=context)
    node.sim_time_s = 0.0
    node.sim_finished = False
    node.controller_stopped = False

    def on_diagnostics(msg):
        for status in msg.status:
            if status.name in MACHINE_NODES:
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


def estop_before_stop(executor, monitor, nodes: dict, wait_s: float = 1.0) -> None:
    """An interrupted run stops the machine before its processes, as the panel's E-stop
    does: the controller brakes the plant and names the stop (cause estop). Stopped
    first, the controller would leave a realtime plant to its watchdog, and the run would
    name that consequence ("watchdog") as its cause. Waits up to ``wait_s`` for the
    controller's stopped status. Whatever fails here, the ordered stop that follows runs."""
    controller = nodes.get("controller") or nodes.get("loop")       # its own process, or the composed loop's
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
    context = rclpy.Context()
    rclpy.init(context=context, args=[], signal_handler_options=SignalHandlerOptions.NO)
    return context


class StopSignals:
    """SIGINT and SIGTERM handled by ``handler`` inside the block, the handlers before
    put back after it (main thread only; elsewhere nothing changes)."""

    def __init__(self, handler):
        self.handler = handler

    def __enter__(self):
        self.saved = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.saved[sig] = signal.signal(sig, self.handler)
        return self

    def __exit__(self, *exc):
        for sig, handler in self.saved.items():
            signal.signal(sig, handler)


def signals_ignored() -> StopSignals:
    """SIGINT/SIGTERM ignored inside the block (main thread only)."""
    return StopSignals(signal.SIG_IGN)


def refuse_if_another_run(executor, monitor, s: Scenario, discovery_s: float = 0.5) -> None:
    """Two runs in one DDS domain and namespace would answer each other's states. Runs of
    this machine are refused by RunLock at once; this looks for any other (a graph
    started by hand) for ``discovery_s``: two of the participants' announcement periods
    (fastdds_localhost_udp.xml, leaseAnnouncement), so that a participant that missed
    this one's first announcements is heard from meanwhile anyway."""
    end = time.monotonic() + discovery_s
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    for topic in ("/clock", s.topic("drives/state")):
        if monitor.count_publishers(topic):
            raise RunFailed(f"another run is active: {topic} already has a publisher in ROS_DOMAIN_ID="
                            f"{os.environ.get('ROS_DOMAIN_ID', '0')}; use another domain (export ROS_DOMAIN_ID=...)")


def publish_start(node, credential: Path) -> None:
    """The latched start signal of a run (controller wait_for_start), with the run's
    credential (pkm_common.credential)."""
    node.start_publisher = publisher(node, START_TOPIC)
    node.start_publisher.publish(start_signal(credential, node.get_fully_qualified_name()))


def refuse_intruders(monitor, s: Scenario) -> None:
    """Only the run's controller may publish drives/command (sim_hw stops on any other:
    refused here before the run starts, naming the node)."""
    topic = s.topic("drives/command")
    names = publisher_names(monitor.get_publishers_info_by_topic(topic))
    others = sorted(set(names) - {controller_node_name(s)})
    if names.count(controller_node_name(s)) > 1:          # an orphan of an earlier run, of the same name
        others.append(f"a second {controller_node_name(s)}")
    if others:
        raise RunFailed(f"intruder: {', '.join(others)} publishes on {topic}, where only {controller_node_name(s)} "
                        "may; stop it or use another domain")


def connected(monitor, s: Scenario) -> bool:
    """Every stream has its publisher; every edge of the loop its subscriber too."""
    edges = ["drives/state", "drives/command"]
    if s.metrology or s.laser_tracker is not None:
        edges.append("platform/true_pose")
    topic = STRATEGIES[s.strategy].metrology_topic
    if topic:
        edges.append(topic)
    for topic in expected_topics(s):
        name = s.topic(topic)
        if monitor.count_publishers(name) < 1 or (topic in edges and monitor.count_subscribers(name) < 1):
            return False
    return True


def scheduling_of(s: Scenario, node: str):
    """The realtime profile's scheduling of ``node`` when the scenario asks for it."""
    return scheduling(node) if s.realtime_profile else None


def run_processes(s: Scenario, run_dir: Path, params: dict, progress: Progress, codes: dict,
                  interruption=None, reserve=None) -> dict:
    """The scenario as separate processes; fills and returns ``codes`` (exit codes).
    Raises RunFailed. ``interruption``: the run's _Interruption (signalled: an E-stop
    before the ordered stop)."""
    context = init_context()
    executor = EventsExecutor(context=context)
    monitor = monitor_node(context, s.namespace)
    executor.add_node(monitor)
    # matched with the controller from the start: an interrupt's E-stop goes out at once
    monitor.estop_publisher = publisher(monitor, topics.ESTOP)
    nodes = {}

    def check_alive(allowed_done=()):
        for node in nodes.values():
            if not node.running() and node.name not in allowed_done:
                raise node_died(node.name, node.popen.returncode, node.tail())
    try:
        # the domain must be the run's own before anything of the run joins it; meanwhile
        # the node server finishes its imports (processes.start_node_server), then every
        # node starts at once, the planner too; the loop starts at the start signal, once
        # the graph is connected, the recorder ready and the planner up (a planner still
        # importing stalled a running loop)
        refuse_if_another_run(executor, monitor, s)
        composed = [name for name in COMPOSED if name in params] if s.loop_process == "composed" else []
        for name in START_ORDER + ("trajectory",):
            if name in params and name not in composed:
                nodes[name] = start_node(name, s.namespace, run_dir / "params" / f"{name}.yaml",
                                         run_dir / "logs", os.environ.copy(), scheduling_of(s, name))
        if composed:                         # the loop's nodes in one process (composed_loop)
            nodes["loop"] = start_node("loop", s.namespace, None, run_dir / "logs", os.environ.copy(),
                                       scheduling_of(s, "loop"), args=[str(run_dir / "params"), *composed])
        ready = run_dir / "recorder.ready"
        deadline = time.monotonic() + CONNECT_TIMEOUT_S
        while not (connected(monitor, s) and (not s.record or ready.exists()) and
                   ("trajectory" not in params or monitor.count_publishers(s.topic("trajectory")) > 0)):
            check_alive()
            refuse_intruders(monitor, s)
            if time.monotonic() > deadline:
                raise RunFailed(f"graph not connected within {CONNECT_TIMEOUT_S:g} s (see {run_dir / 'logs'})")
            executor.spin_once(timeout_sec=0.05)
        # the controller answers from then on (with a program: once its trajectory is there)
        publish_start(monitor, Path(params["controller"]["credential_file"]))
        deadline = time.monotonic() + s.timeout_s
        machine = "loop" if "loop" in nodes else s.machine_node      # the process the plant runs in
        sim = nodes[machine]
        # the loop is over when the sim has exited, or LOOP_END_GRACE_S after it finished
        # (its last diagnostics, or its summary file, written before it shuts down: the
        # exit of a process with compiled kernels takes ~0.4 s, close to the
        # controller's state watchdog; the grace lets the last state be answered)
        sim_summary = run_dir / "summaries" / f"{s.machine_node}.json"
        finished_wall = math.inf
        while sim.running() and time.monotonic() < finished_wall + LOOP_END_GRACE_S:
            check_alive(allowed_done=(machine,))
            if time.monotonic() > deadline:
                raise RunFailed(f"timeout_s: the run did not end within {s.timeout_s:g} s (wall clock)")
            executor.spin_once(timeout_sec=0.02)
            progress.update(monitor.sim_time_s)
            if finished_wall == math.inf and (monitor.sim_finished or summary_written(sim_summary)):
                finished_wall = time.monotonic()
                # the loop is over: the recorder's idle priority would starve the last
                # batches, which the nodes now wait for it to take (node_tap.close: 2 s);
                # on a loaded machine an idle recorder took none of the plant's last batch
                if "recorder" in nodes:
                    normal_cpu_priority(nodes["recorder"].popen.pid)
        progress.update(s.duration_s)
        if "recorder" in nodes:       # (if the plant ended without saying so)
            normal_cpu_priority(nodes["recorder"].popen.pid)
        # stop the loop's nodes at once (their watchdogs would report the silent
        # plant), then give the recorder time for the last messages
        # (the virtual drives, the machine's physics, stay until the machine's node has exited)
        codes.update(stop_nodes([nodes[n] for n in STOP_ORDER
                                 if n in nodes and n not in ("recorder", machine) + BEHIND], together=True))
        with contextlib.suppress(subprocess.TimeoutExpired):     # the sim ends by itself
            sim.popen.wait(timeout=10.0)
        if sim.popen.returncode is None:
            raise RunFailed(f"node {machine} finished but did not exit within 10 s; its last output:\n{sim.tail()}")
        if sim.popen.returncode != 0:
            raise node_died(machine, sim.popen.returncode, sim.tail())
        end = time.monotonic() + DRAIN_S
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
    finally:
        progress.done()
        if reserve is not None:               # the nodes' summaries and run.json get the space kept for them
            reserve.release()
        with signals_ignored():              # a second Ctrl-C must not abandon the ordered stop
            if interruption is not None and interruption.signalled:
                estop_before_stop(executor, monitor, nodes)
            codes.update(stop_nodes([nodes[n] for n in STOP_ORDER if n in nodes]))
        executor.shutdown()
        monitor.destroy_node()
        end_context(context)
    return codes


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
