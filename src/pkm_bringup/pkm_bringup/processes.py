"""Child processes of a run: started so that none can outlive the orchestrator.

Each node runs as ``python -m <module> --ros-args -r __ns:=<ns> --params-file <file>``
(or held after its imports until released: ``held_node``)
in its own session (a Ctrl-C in the terminal reaches the orchestrator only, which then
stops the nodes in order: the recorder last, so that it finalizes a complete bag), with
``PR_SET_PDEATHSIG`` = SIGTERM: if the orchestrator itself dies (even by kill -9), the
kernel terminates its children. stdout and stderr go to ``logs/<node>.log``.

With a ``Scheduling`` of the realtime profile (rt_profile.py), the child gets its
policy between fork and exec (every thread it creates inherits it) and, when it locks
its memory, ``PKM_MLOCKALL=1`` in its environment (honoured by
``pkm_common.runner.run_node``).
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from pkm_bringup.rt_profile import Scheduling, child_environment, preexec
from pkm_common.domains import PROFILE_ENV, claim_domain_id, localhost_dds

MODULES = {
    "recorder": "pkm_recording.recorder_node",
    "sim_hw": "pkm_sim_hw.sim_hw_node",
    "drives": "pkm_drives.drives_node",
    "virtual_drives": "pkm_drives.virtual_drives_node",
    "ros2_control": "pkm_drives.ros2_control_node",
    "ros2_control_sim": "pkm_drives.ros2_control_sim_node",
    "gough_sensor": "pkm_gough_sensor.gough_sensor_node",
    "laser_tracker": "pkm_gough_sensor.laser_tracker_node",
    "controller": "pkm_controller.controller_node",
    "trajectory": "pkm_trajectory.trajectory_node",
}
_PR_SET_PDEATHSIG = 1
try:                                      # loaded here, not after fork (dlopen in a forked
    _PRCTL = ctypes.CDLL("libc.so.6", use_errno=True).prctl      # multi-threaded process can deadlock)
except (OSError, AttributeError):
    _PRCTL = None


def die_with_parent() -> None:          # runs in the child between fork and exec
    if _PRCTL is not None:
        _PRCTL(_PR_SET_PDEATHSIG, signal.SIGTERM)


@dataclass
class NodeProcess:
    name: str
    popen: subprocess.Popen
    log: Path

    def running(self) -> bool:
        return self.popen.poll() is None

    def release(self) -> None:
        """A held node (``start_node(hold=True)``): run it now (held_node). A node
        that already ended is left to the run's checks."""
        if self.popen.stdin is None:
            return
        try:
            self.popen.stdin.write(b"go\n")
            self.popen.stdin.close()
        except (BrokenPipeError, OSError):
            pass
        self.popen.stdin = None

    def tail(self, lines: int = 25) -> str:
        try:
            text = self.log.read_text(encoding="utf-8", errors="replace").splitlines()
        except OSError:
            return ""
        return "\n".join(text[-lines:])


def start_node(name: str, namespace: str, params_file: Path, log_dir: Path, env: dict,
               scheduling: Scheduling | None = None, hold: bool = False) -> NodeProcess:
    """Start node ``name``; ``scheduling``: its realtime profile (None: as this process);
    ``hold``: imported but held until ``release`` (pkm_bringup.held_node), without DDS."""
    log = log_dir / f"{name}.log"
    module = ["pkm_bringup.held_node", MODULES[name]] if hold else [MODULES[name]]
    args = [sys.executable, "-u", "-m", *module, "--ros-args", "-r", f"__ns:={namespace}",
            "--params-file", str(params_file)]
    preexec_fn = die_with_parent
    if scheduling is not None:
        env = child_environment(env, scheduling)
        preexec_fn = preexec(scheduling, before=die_with_parent)
    with log.open("w") as out:
        popen = subprocess.Popen(args, env=env, stdout=out, stderr=subprocess.STDOUT,
                                 stdin=subprocess.PIPE if hold else subprocess.DEVNULL,
                                 start_new_session=True, preexec_fn=preexec_fn)
    return NodeProcess(name, popen, log)


def _wait_or_kill(node: NodeProcess, timeout_s: float) -> None:
    try:
        node.popen.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        node.popen.kill()
        node.popen.wait()


def stop_nodes(nodes: list[NodeProcess], timeout_s: float = 10.0, together: bool = False) -> dict[str, int]:
    """SIGTERM each running node in the given order, waiting for each to exit (the
    runner finalizes on SIGTERM), or all at once with ``together``; SIGKILL what does
    not exit in ``timeout_s``. Returns the exit codes."""
    for node in nodes:
        if node.running():
            node.popen.send_signal(signal.SIGTERM)
            if not together:
                _wait_or_kill(node, timeout_s)
    for node in nodes:
        _wait_or_kill(node, timeout_s)
    return {node.name: node.popen.returncode for node in nodes}


def ros_environment(own_domain: bool = False) -> dict:
    """The process environment with a DDS domain (ROS_DOMAIN_ID kept if set, else one
    claimed for this process: no live process on the host holds it) and the DDS kept on
    localhost (pkm_common.domains.localhost_dds). ``own_domain`` claims one even if
    ROS_DOMAIN_ID is set: for a graph that must stay apart from the graph of whoever
    started this process (a benchmark started by a test, whose worker runs its own
    graphs in the domain it passed down)."""
    env = localhost_dds(os.environ)
    if own_domain or "ROS_DOMAIN_ID" not in env:
        env["ROS_DOMAIN_ID"] = str(claim_domain_id())
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def use_ros_environment() -> dict:
    """``ros_environment`` for the children, its ROS_ variables applied to this process
    too (so that its own nodes join the same domain); returns it."""
    env = ros_environment()
    os.environ.update({k: v for k, v in env.items() if k.startswith("ROS_") or k == PROFILE_ENV})
    return env
