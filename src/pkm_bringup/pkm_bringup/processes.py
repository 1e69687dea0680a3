"""Child processes of a run: started so that none can outlive the orchestrator.

Every node is forked from the run's node server (``multiprocessing``'s fork server,
``node_server``): one clean process that has imported the nodes' modules (rclpy,
numpy, numba and the compiled kernels: ~2 s of CPU, ~1.4 s of it in every node when
each imported its own), started early (pkm-run starts it before its own imports,
``start_node_server``) and forking a node in milliseconds. The child then is what
``python -m <module> --ros-args -r __ns:=<ns> --params-file <file>`` was: in its own
session (a Ctrl-C in the terminal reaches the orchestrator only, which then stops the
nodes in order: the recorder last, so that it finalizes a complete bag), with
``PR_SET_PDEATHSIG`` = SIGTERM (its parent, the server, ends with the orchestrator,
even one killed with kill -9: so does every node), its environment the run's,
stdout and stderr in ``logs/<node>.log``. The server leaves pkm-run's session and
ignores the signals meant for pkm-run (node_server_init). Limits: what a node reads
from its environment at import (NUMBA_CACHE_DIR, PKM_NO_JIT, PYTHONPATH) is the
server's, and so is its /proc/<pid>/environ (pkm-run starts the server with the run's
ROS_DOMAIN_ID: pkm_common.domains finds the domain there). A caller that may not fork
(a daemonic multiprocessing process: a Dask worker) starts each node as its own
interpreter instead (``python -u -m <module>``).

With a ``Scheduling`` of the realtime profile (rt_profile.py), the child takes its
policy before it runs the node (every thread it creates inherits it) and, when it
locks its memory, ``PKM_MLOCKALL=1`` in its environment (honoured by
``pkm_common.runner.run_node``).
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import multiprocessing
import multiprocessing.forkserver
import os
import signal
import subprocess
import sys
import threading
import time
import types
from dataclasses import dataclass
from pathlib import Path

from pkm_bringup.node_server_init import IGNORED as IGNORED_BY_THE_SERVER
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
    "loop": "pkm_bringup.composed_loop",          # sim_hw, the instruments and the controller in one process
}
# what the node server imports before it forks a node: the nodes of a simulated run (a
# drive interface's node imports its own bus and protocol after the fork)
PRELOAD = ("pkm_bringup.node_server_init",) + tuple(
    MODULES[name] for name in ("recorder", "sim_hw", "gough_sensor", "laser_tracker", "controller", "trajectory",
                               "loop"))
_PR_SET_PDEATHSIG, _PR_SET_NAME = 1, 15
try:                                      # loaded here, not after fork (dlopen in a forked
    _PRCTL = ctypes.CDLL("libc.so.6", use_errno=True).prctl      # multi-threaded process can deadlock)
except (OSError, AttributeError):
    _PRCTL = None


def die_with_parent() -> None:          # runs in the child between fork and exec
    if _PRCTL is not None:
        _PRCTL(_PR_SET_PDEATHSIG, signal.SIGTERM)


def die_with_parent_checked() -> None:
    """``die_with_parent``, in a child that may have outlived its parent already."""
    parent = os.getppid()
    die_with_parent()
    if os.getppid() != parent:
        os.kill(os.getpid(), signal.SIGTERM)


def node_server():
    """The multiprocessing context of the node server (module docstring)."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(list(PRELOAD))
    return context


def start_node_server() -> None:
    """Start the node server now, its imports running while the caller does its own;
    the first ``start_node`` waits for them."""
    node_server()
    multiprocessing.forkserver.ensure_running()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class ForkedProcess:
    """A node forked by the node server, with the part of subprocess.Popen's interface
    a run uses (pid, returncode, poll, wait, send_signal, kill). Its exit code comes
    from the server; a server that died (an OOM kill) leaves multiprocessing saying 255
    at once: a node still alive then is said running until it ends (its death
    signal, PR_SET_PDEATHSIG, ends it), and is still signalled."""

    LOST = 255                     # multiprocessing's exit code when the server's pipe closed

    def __init__(self, process, args: list):
        self.process, self.args = process, args

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def returncode(self) -> int | None:
        return self.poll()

    def poll(self) -> int | None:
        code = self.process.exitcode
        if code == self.LOST and _alive(self.process.pid):
            return None
        return code

    def wait(self, timeout: float | None = None) -> int:
        end = None if timeout is None else time.monotonic() + timeout
        self.process.join(timeout)
        while self.poll() is None:
            if end is not None and time.monotonic() >= end:
                raise subprocess.TimeoutExpired(self.args, timeout)
            time.sleep(0.01)                # a node the lost server can no longer report
        return self.poll()

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.process.pid, sig)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


def _let_the_server_end() -> None:
    """multiprocessing hands every child of the fork server the write end of the pipe
    whose end tells the server that its clients are gone (so that a child could use the
    server too): a node holding it would keep the server, whose death is the node's
    (PR_SET_PDEATHSIG), alive after pkm-run's death. Closed: the server ends with
    pkm-run, and every node with the server (tests/bringup/test_node_server.py)."""
    server = getattr(multiprocessing.forkserver, "_forkserver", None)
    fd = getattr(server, "_forkserver_alive_fd", None)
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)
        server._forkserver_alive_fd = None


_STARTING = threading.Lock()


@contextlib.contextmanager
def _without_main_module():
    """A node needs its own module only: multiprocessing would have the child run the
    caller's main script again first (as ``__mp_main__``: a script that runs a scenario
    at its top level would run it in every node) unless the caller's ``__main__`` has
    neither a file nor a module name while the child is prepared (one start at a time:
    the swap is the process's)."""
    with _STARTING:
        main = sys.modules["__main__"]
        sys.modules["__main__"] = types.ModuleType("__main__")
        try:
            yield
        finally:
            sys.modules["__main__"] = main


def run_forked(name: str, argv: list, env: dict, log: str, scheduling: Scheduling | None) -> None:
    """A node in the child the node server forked (start_node): the default
    dispositions of the signals the server ignores (node_server_init; first, or its
    death signal would be ignored too), its parent's death, its name, its log (what
    fails after it is said there), its session, its policy, its environment, then the
    module's ``main`` with the node's arguments."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for sig in IGNORED_BY_THE_SERVER:
        if sig != signal.SIGINT:
            signal.signal(sig, signal.SIG_DFL)
    die_with_parent_checked()
    if _PRCTL is not None:                  # ps and top name the node (the command line is the server's);
        _PRCTL(_PR_SET_NAME, f"pkm:{name}"[:15].encode())    # before its log, by which node_pids finds it
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.stdout = open(1, "w", buffering=1, encoding="utf-8", closefd=False)   # noqa: SIM115 - the process's
    sys.stderr = open(2, "w", buffering=1, encoding="utf-8", closefd=False)   # noqa: SIM115
    os.setsid()
    _let_the_server_end()
    if scheduling is not None:
        preexec(scheduling)()
    os.environ.clear()
    os.environ.update(env)
    module = importlib.import_module(MODULES[name])
    sys.argv = [module.__file__, *argv]
    code = module.main()                    # a node's main exits itself (runner.main_exit); a usage error returns
    if code:
        sys.exit(code)


@dataclass
class NodeProcess:
    name: str
    popen: subprocess.Popen | ForkedProcess
    log: Path

    def running(self) -> bool:
        return self.popen.poll() is None

    def tail(self, lines: int = 25) -> str:
        try:
            text = self.log.read_text(encoding="utf-8", errors="replace").splitlines()
        except OSError:
            return ""
        return "\n".join(text[-lines:])


def start_node(name: str, namespace: str, params_file: Path | None, log_dir: Path, env: dict,
               scheduling: Scheduling | None = None, args=()) -> NodeProcess:
    """Start node ``name``, forked by the node server (module docstring; the first
    waits for the server's imports); ``scheduling``: its realtime profile (None: as
    this process); ``args``: before the ROS arguments (the composed loop's: its
    params directory and nodes); ``params_file`` None: none."""
    log = log_dir / f"{name}.log"
    log.write_text("")
    argv = [*args, "--ros-args", "-r", f"__ns:={namespace}"]
    if params_file is not None:
        argv += ["--params-file", str(params_file)]
    if scheduling is not None:
        env = child_environment(env, scheduling)
    if multiprocessing.current_process().daemon:      # a Dask worker's: it may not fork children of its own
        return _spawn_node(name, argv, env, log, scheduling)
    process = node_server().Process(target=run_forked, name=f"pkm-{name}", daemon=True,
                                    args=(name, argv, dict(env), str(log), scheduling))
    try:
        with _without_main_module():
            process.start()
    except (EOFError, ConnectionError, FileNotFoundError) as exc:
        raise RuntimeError(f"the node server is not running ({type(exc).__name__}: {exc}); its own error is on "
                           "this process's stderr") from None
    return NodeProcess(name, ForkedProcess(process, [MODULES[name], *argv]), log)


def _spawn_node(name: str, argv: list, env: dict, log: Path, scheduling: Scheduling | None) -> NodeProcess:
    """``python -u -m <module> <argv>``: a node of its own interpreter, for a caller that
    may not fork (multiprocessing's daemonic processes), as nodes were started before
    the node server."""
    preexec_fn = die_with_parent if scheduling is None else preexec(scheduling, before=die_with_parent)
    with log.open("w") as out:
        popen = subprocess.Popen([sys.executable, "-u", "-m", MODULES[name], *argv], env=env, stdout=out,
                                 stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True,
                                 preexec_fn=preexec_fn)
    return NodeProcess(name, popen, log)


def node_pids(run_dir: Path, proc_dir: str = "/proc") -> dict[str, int]:
    """The live node processes of the run in ``run_dir``, node name -> pid: a node's
    stdout is its ``logs/<node>.log`` (its command line is the node server's); for a
    tool or a test that acts on one node."""
    logs = os.path.realpath(Path(run_dir) / "logs") + os.sep
    found = {}
    for pid in filter(str.isdigit, os.listdir(proc_dir)):
        try:
            target = os.readlink(f"{proc_dir}/{pid}/fd/1")
        except OSError:                   # ended meanwhile, a zombie, or another user's
            continue
        if target.startswith(logs) and target.endswith(".log"):
            found[target[len(logs):-len(".log")]] = int(pid)
    return found


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
