"""The nodes of a run forked by the node server (pkm_bringup.processes): each in its own
session with the run's environment and its log, found by name (node_pids), none left
when the orchestrator is killed, and a script that runs a scenario at its top level
run once (multiprocessing would run the caller's main script again in every child)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from pkm_bringup.processes import node_pids, start_node, stop_nodes


def test_a_forked_node_stays_in_its_own_session_with_the_environment_given(tmp_path):
    """A long-lived forked node (the planner, waiting for goals) is the leader of its
    own session (a terminal's Ctrl-C reaches only pkm-run), named pkm:<node> for ps
    and top, found by its log (node_pids), and runs with the environment it was given,
    not the node server's: PKM_PROFILE_DIR there has its runner write its profile when
    SIGTERM ends it."""
    logs = tmp_path / "logs"
    logs.mkdir()
    params = tmp_path / "trajectory.yaml"
    params.write_text("/**:\n  ros__parameters:\n    machine: archi\n")
    env = {**os.environ, "PKM_PROFILE_DIR": str(tmp_path / "profiles")}
    node = start_node("trajectory", "/t_session", params, logs, env)
    try:
        deadline = time.monotonic() + 30
        while "trajectory" not in node_pids(tmp_path) and time.monotonic() < deadline:
            assert node.running(), node.tail()
            time.sleep(0.02)
        pid = node_pids(tmp_path)["trajectory"]
        assert pid == node.popen.pid
        # named before its log exists (found named); its own session right after the log
        assert Path(f"/proc/{pid}/comm").read_text().strip() == "pkm:trajectory"
        while os.getsid(pid) != pid and time.monotonic() < deadline:
            time.sleep(0.01)
        assert os.getsid(pid) == pid, (os.getsid(pid), pid)
        # the server, in a session of its own, ignores what is meant for pkm-run; the node does not
        server = _parent(pid)
        assert os.getsid(server) == server != os.getsid(0)
        assert _ignored(server) >= {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}, _ignored(server)
        assert not _ignored(pid) & {signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT}, _ignored(pid)
        time.sleep(1.0)                        # built and spinning
        assert node.running(), node.tail()
    finally:
        codes = stop_nodes([node], timeout_s=20)
    assert codes["trajectory"] in (0, -signal.SIGTERM), (codes, node.tail())
    assert (tmp_path / "profiles" / "trajectory.prof").exists(), node.tail()


_SCRIPT = """
from pathlib import Path
import sys
with open(sys.argv[2], "a") as f:          # at the top level: run once, not again in a node
    f.write("ran\\n")
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.processes import use_ros_environment
from pkm_bringup.scenario import load_scenario
use_ros_environment()
s = load_scenario("mom3_square", {"duration_s": float(sys.argv[3]), "record": False})
run = run_scenario(s, Path(sys.argv[1]), in_process=False, progress=False, report=False)
print(run["status"], run["error"])
"""


@pytest.mark.slow
def test_a_script_running_a_scenario_at_its_top_level_runs_once_and_its_nodes_die_with_it(tmp_path):
    """A user's script without a ``__main__`` guard runs a scenario as processes: the
    run completes and the script's top level ran once. Then the same script with a
    long run, killed with SIGKILL once its loop runs: every node ends (their parent,
    the node server, ends with the script; each node has PR_SET_PDEATHSIG)."""
    script = tmp_path / "run_it.py"
    script.write_text(textwrap.dedent(_SCRIPT))
    marks = tmp_path / "marks.txt"
    out = subprocess.run([sys.executable, str(script), str(tmp_path / "short"), str(marks), "0.2"],
                         capture_output=True, text=True, timeout=180)
    assert out.returncode == 0 and "completed" in out.stdout, out.stdout + out.stderr
    assert marks.read_text() == "ran\n", marks.read_text()

    run_dir = tmp_path / "long"
    proc = subprocess.Popen([sys.executable, str(script), str(run_dir), str(marks), "60"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        log = run_dir / "logs" / "sim_hw.log"
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if log.exists() and "loop started" in log.read_text(errors="replace"):
                break
            time.sleep(0.05)
        before = node_pids(run_dir)
        assert set(before) == {"sim_hw", "gough_sensor", "controller", "trajectory"}, before
        servers = {_parent(pid) for pid in before.values()}          # the node server, the nodes' parent
        assert len(servers) == 1 and proc.pid not in servers, (servers, proc.pid)
    finally:
        proc.kill()
        proc.wait()
    deadline = time.monotonic() + 20
    while (node_pids(run_dir) or Path(f"/proc/{next(iter(servers))}").exists()) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not node_pids(run_dir), (before, node_pids(run_dir))
    assert not Path(f"/proc/{next(iter(servers))}").exists(), "the node server outlived its client"


def _ignored(pid: int) -> set[int]:
    """The signals ``pid`` ignores (/proc/<pid>/status SigIgn)."""
    mask = int(next(line.split()[1] for line in Path(f"/proc/{pid}/status").read_text().splitlines()
                    if line.startswith("SigIgn:")), 16)
    return {sig for sig in range(1, 65) if mask >> (sig - 1) & 1}


def _parent(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def test_a_caller_that_may_not_fork_starts_each_node_as_its_own_interpreter(tmp_path, monkeypatch):
    """In a daemonic multiprocessing process (a Dask worker) multiprocessing refuses
    children: the node is started as ``python -u -m <module>`` instead, with its log
    and its session, and ends on SIGTERM (before its runner's handler exists, by it)."""
    import multiprocessing
    monkeypatch.setitem(multiprocessing.current_process()._config, "daemon", True)
    logs = tmp_path / "logs"
    logs.mkdir()
    params = tmp_path / "trajectory.yaml"
    params.write_text("/**:\n  ros__parameters:\n    machine: archi\n")
    node = start_node("trajectory", "/t_spawned", params, logs, dict(os.environ))
    try:
        cmdline = Path(f"/proc/{node.popen.pid}/cmdline").read_bytes().split(b"\0")
        assert b"pkm_trajectory.trajectory_node" in cmdline, cmdline
        deadline = time.monotonic() + 30
        while "trajectory" not in node_pids(tmp_path) and time.monotonic() < deadline:
            assert node.running(), node.tail()
            time.sleep(0.02)
        assert node_pids(tmp_path) == {"trajectory": node.popen.pid}
        assert os.getsid(node.popen.pid) == node.popen.pid
    finally:
        codes = stop_nodes([node], timeout_s=20)
    assert codes["trajectory"] in (0, -signal.SIGTERM), (codes, node.tail())
