"""The scenario's nodes in one executor (``pkm-run --in-process``: fast tests, studies,
the gallery): the same nodes and parameters as graph.run_processes, in lockstep the same
run. Imported only by a run in one process: it loads every node's module.
"""

from __future__ import annotations

import time
from pathlib import Path

from rclpy.experimental import EventsExecutor
from rclpy.parameter import Parameter

from pkm_bringup.graph import (CONNECT_TIMEOUT_S, DRAIN_IN_PROCESS_S, START_ORDER, STOP_ORDER, Progress, RunFailed,
                               end_context, init_context, monitor_node, publish_start, refuse_if_another_run,
                               signals_ignored)
from pkm_bringup.scenario import Scenario
from pkm_common.runner import start_up_frozen, warm_log_caller_lookup
from pkm_controller.controller_node import ControllerNode
from pkm_gough_sensor.gough_sensor_node import GoughSensorNode
from pkm_gough_sensor.laser_tracker_node import LaserTrackerNode
from pkm_recording.recorder_node import RecorderNode
from pkm_drives.drives_node import DrivesNode
from pkm_drives.virtual_drives_node import VirtualDrivesNode
from pkm_sim_hw.sim_hw_node import SimHwNode
from pkm_trajectory.trajectory_node import TrajectoryNode


def run_in_process(s: Scenario, run_dir: Path, params: dict, progress: Progress, codes: dict,
                   interruption=None, reserve=None) -> dict:
    """The scenario with every node in one EventsExecutor (same parameters); an
    interruption stops every node at once (no plant runs on without its controller)."""

    if s.hardware == "ros2_control":
        raise RunFailed("hardware ros2_control runs as processes: its system (or its stand-in) runs its own "
                        "real-time loop, which one executor would stop while the interface waits for it")
    classes = {"recorder": RecorderNode, "sim_hw": SimHwNode, "gough_sensor": GoughSensorNode,
               "controller": ControllerNode, "trajectory": TrajectoryNode, "drives": DrivesNode,
               "virtual_drives": VirtualDrivesNode, "laser_tracker": LaserTrackerNode}
    context = init_context()
    executor = EventsExecutor(context=context)
    nodes = {}

    def create(name):
        values = dict(params[name])
        if name in ("sim_hw", "drives"):
            values["shutdown_on_finish"] = False
        if name == "virtual_drives":          # one process: the drives' virtual channel, no bridge
            values.pop("bridge_url_file", None)
        if name == "drives" and "virtual_drives" in params:
            values.update(can_interface="virtual", can_channel=params["virtual_drives"]["can_channel"])
            values.pop("can_channel_file", None)
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
        monitor = monitor_node(context, s.namespace)
        executor.add_node(monitor)
        refuse_if_another_run(executor, monitor, s)
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
        starter = monitor_node(context, s.namespace)
        executor.add_node(starter)
        nodes["starter"] = starter
        publish_start(starter, Path(params["controller"]["credential_file"]))
        deadline = time.monotonic() + s.timeout_s
        sim = nodes[s.machine_node]
        last = 0.0
        warm_log_caller_lookup()
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
        with signals_ignored():
            close(STOP_ORDER)
        executor.shutdown()
        end_context(context)
    codes.update({name: 0 for name in params})
    return codes
