"""pkm-run's realtime profile (pkm_bringup.rt_profile): who gets which policy, the
refusal where the OS does not allow it, the memory lock of run_node, and (slow) a run
whose loop nodes really run SCHED_FIFO with locked memory.

The machine of these tests runs them as root, so the real calls succeed; the refusal
is tested by making sched_setscheduler fail with EPERM (monkeypatch)."""

import errno
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from pkm_bringup import rt_profile
from pkm_bringup.orchestrator import main as pkm_run_main
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.processes import node_pids
from pkm_bringup.rt_profile import (FIFO, OTHER, PROFILE, Permissions, RealtimeProfileRefused, Scheduling, refusal,
                                    scheduling)
from pkm_bringup.scenario import ScenarioError, load_scenario
from pkm_common.runner import EXIT_BAD_PARAMETER, EXIT_OK, MEMORY_LOCK_ENV, run_node

PERMITTED = Permissions(priority=80, fifo_errno=None, rtprio_limit=0, cap_sys_nice=True, mlock_errno=None,
                        memlock_limit_bytes=8 * 2**20, cap_ipc_lock=True)


def _locked_kib(pid="self") -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmLck:"):
            return int(line.split()[1])
    raise AssertionError("no VmLck in /proc/<pid>/status")


def test_the_loop_nodes_run_sched_fifo_in_the_order_of_the_critical_path_and_the_rest_unchanged():
    sim, ctrl, sensor = scheduling("sim_hw"), scheduling("controller"), scheduling("gough_sensor")
    assert {sim.policy, ctrl.policy, sensor.policy} == {FIFO}
    assert ctrl.priority > sensor.priority > sim.priority >= 1      # the path: readings, then the command
    assert sim.lock_memory and ctrl.lock_memory and sensor.lock_memory
    for node in ("recorder", "trajectory"):                            # below every SCHED_FIFO thread anyway
        assert scheduling(node) == Scheduling(OTHER, 0, lock_memory=False)
    loop = scheduling("loop")                      # the composed loop: one thread, at the profile's highest priority
    assert loop.policy == FIFO and loop.lock_memory and loop.priority == max(p.priority for p in PROFILE.values())
    assert set(PROFILE) == {"sim_hw", "controller", "gough_sensor", "loop", "recorder", "trajectory", "drives",
                            "virtual_drives", "ros2_control", "ros2_control_sim"}
    assert scheduling("drives") == scheduling("virtual_drives") == sim     # the machine's place on the path
    one = scheduling("recorder", in_process=True)                      # one process: all of it at the loop's
    assert one.policy == FIFO and one.priority == ctrl.priority and one.lock_memory
    with pytest.raises(ValueError, match="node: must be one of"):
        scheduling("planner")
    with pytest.raises(ValueError, match=r"priority: must be in \[1, 99\] for fifo, got 0"):
        Scheduling(FIFO, 0)


def test_child_environment_asks_run_node_for_the_lock_only_where_the_profile_locks():
    env = {"A": "1", MEMORY_LOCK_ENV: "1"}
    assert rt_profile.child_environment(env, scheduling("controller"))[MEMORY_LOCK_ENV] == "1"
    assert MEMORY_LOCK_ENV not in rt_profile.child_environment(env, scheduling("recorder"))
    assert env == {"A": "1", MEMORY_LOCK_ENV: "1"}                       # not changed in place


def test_refusal_names_what_is_missing_in_one_line():
    assert refusal(PERMITTED) is None
    no_fifo = Permissions(80, errno.EPERM, 0, False, None, 8 * 2**20, False)
    message = refusal(no_fifo)
    assert message == ("realtime profile: SCHED_FIFO priority 80 not permitted (EPERM; needs root or CAP_SYS_NICE "
                       "(has it: no), or an rtprio limit of at least 80: ulimit -r is 0); run without --rt-profile "
                       "(scenario: realtime_profile: false)")
    no_lock = Permissions(80, None, 0, True, None, 8 * 2**20, False)
    assert refusal(no_lock) == ("realtime profile: memory locking not permitted (mlockall needs root or "
                                "CAP_IPC_LOCK, or an unlimited memlock limit: ulimit -l is 8192 KiB); run without "
                                "--rt-profile (scenario: realtime_profile: false)")
    assert refusal(no_lock, lock=False) is None
    assert refusal(Permissions(80, None, 0, True, None, None, False)) is None          # ulimit -l unlimited
    assert "EPERM on mlock" in refusal(Permissions(80, None, 0, True, errno.EPERM, None, True))
    assert all("\n" not in m for m in (message, refusal(no_lock)))


def test_the_scenario_key_is_validated_and_off_by_default(tmp_path):
    assert load_scenario("mom3_square").realtime_profile is False
    assert load_scenario("mom3_square", {"realtime_profile": True}).realtime_profile is True
    with pytest.raises(ScenarioError, match="realtime_profile: must be true or false, got 'yes'"):
        load_scenario("mom3_square", {"realtime_profile": "yes"})


def test_the_loop_is_composed_by_default_with_the_profile_only_on_the_simulated_machine():
    """loop_process: composed with the realtime profile, separate without it (and in
    every lockstep run), either when asked; composed only on sim_hw, a bad value named."""
    assert load_scenario("mom3_square").loop_process == "separate"
    assert load_scenario("mom3_square", {"realtime_profile": True}).loop_process == "composed"
    assert load_scenario("mom3_square", {"realtime_profile": True, "loop_process": "separate"}).loop_process == \
        "separate"
    assert load_scenario("mom3_square", {"loop_process": "composed"}).loop_process == "composed"
    assert load_scenario("archi_canopen", {"realtime_profile": True}).loop_process == "separate"
    with pytest.raises(ScenarioError, match="^loop_process: composed runs the simulated machine's loop "
                                            r"\(hardware: sim\), not hardware canopen"):
        load_scenario("archi_canopen", {"loop_process": "composed"})
    with pytest.raises(ScenarioError, match="^loop_process: must be one of separate, composed, got 'one'"):
        load_scenario("mom3_square", {"loop_process": "one"})


def _eperm(*args):
    raise PermissionError(errno.EPERM, "Operation not permitted")


@pytest.mark.parametrize("how", ["flag", "scenario_key"])
def test_pkm_run_refuses_without_sched_fifo_and_starts_nothing(tmp_path, monkeypatch, capsys, how):
    monkeypatch.setattr(os, "sched_setscheduler", _eperm)
    monkeypatch.setattr(rt_profile, "_soft_limit", lambda which: 0)              # ulimit -r 0 (and -l 0)
    monkeypatch.setattr(rt_profile, "_capabilities", lambda: 0)
    started = []
    monkeypatch.setattr("pkm_bringup.processes.start_node", lambda *a, **k: started.append(a))
    run_dir = tmp_path / "refused"
    if how == "flag":
        argv = ["mom3_square", "--rt-profile"]
    else:
        scenario = tmp_path / "rt.yaml"
        scenario.write_text(yaml.safe_dump({"machine": "mom3", "duration_s": 0.5, "metrology": True,
                                                "realtime_profile": True}))
        argv = [str(scenario)]
    assert pkm_run_main([*argv, "--run-dir", str(run_dir), "--no-progress"]) == 2
    out, err = capsys.readouterr()
    assert err == ("pkm-run: realtime profile: SCHED_FIFO priority 80 not permitted (EPERM; needs root or "
                   "CAP_SYS_NICE (has it: no), or an rtprio limit of at least 80: ulimit -r is 0); run without "
                   "--rt-profile (scenario: realtime_profile: false)\n")
    assert out == "" and not run_dir.exists() and not started
    # through the API: refused before the run directory is made
    with pytest.raises(RealtimeProfileRefused, match="SCHED_FIFO priority 80 not permitted"):
        run_scenario(load_scenario("mom3_square", {"realtime_profile": True}), run_dir, progress=False)
    assert not run_dir.exists()


def test_pkm_run_refuses_when_memory_cannot_be_locked(tmp_path, monkeypatch, capsys):
    """SCHED_FIFO allowed (real, as root), but no CAP_IPC_LOCK and ulimit -l 8 MiB."""
    monkeypatch.setattr(rt_profile, "_capabilities", lambda: 1 << 23)            # CAP_SYS_NICE only
    monkeypatch.setattr(rt_profile, "_soft_limit", lambda which: 8 * 2**20)
    assert pkm_run_main(["mom3_square", "--rt-profile", "--run-dir", str(tmp_path / "x"), "--no-progress"]) == 2
    assert capsys.readouterr().err == (
        "pkm-run: realtime profile: memory locking not permitted (mlockall needs root or CAP_IPC_LOCK, or an "
        "unlimited memlock limit: ulimit -l is 8192 KiB); run without --rt-profile (scenario: realtime_profile: "
        "false)\n")
    assert not (tmp_path / "x").exists()


def test_the_probe_leaves_this_process_as_it_was():
    before = [(t, os.sched_getscheduler(int(t))) for t in os.listdir("/proc/self/task")]
    permissions = rt_profile.probe_permissions()
    assert permissions.fifo_errno is None and permissions.priority == 80     # root here
    assert [(t, os.sched_getscheduler(int(t))) for t in os.listdir("/proc/self/task")] == before
    assert _locked_kib() == 0


def test_in_process_profile_applies_to_every_thread_and_is_undone_after():
    assert os.sched_getscheduler(0) == os.SCHED_OTHER and _locked_kib() == 0
    with rt_profile.applied_to_this_process():
        tids = [int(t) for t in os.listdir("/proc/self/task")]
        assert all(os.sched_getscheduler(t) == os.SCHED_FIFO for t in tids)
        assert os.sched_getparam(0).sched_priority == rt_profile.IN_PROCESS.priority
        assert _locked_kib() > 0
    assert all(os.sched_getscheduler(int(t)) == os.SCHED_OTHER for t in os.listdir("/proc/self/task"))
    assert _locked_kib() == 0


@pytest.mark.ros
def test_run_node_locks_memory_when_asked_and_unlocks_after(monkeypatch):
    from rclpy.node import Node
    seen = []

    def factory(context):
        node = Node("runner_locked", context=context)
        node.create_timer(0.01, lambda: (seen.append(_locked_kib()), context.try_shutdown()))
        return node
    monkeypatch.setenv(MEMORY_LOCK_ENV, "1")
    assert run_node(factory, args=[]) == EXIT_OK
    assert seen and seen[0] > 0                  # locked while spinning
    assert _locked_kib() == 0                    # an embedding process is left as it was


@pytest.mark.ros
def test_run_node_exits_2_naming_a_failed_memory_lock(monkeypatch, capfd):
    from rclpy.node import Node

    def no_lock():
        raise OSError(errno.ENOMEM, "mlockall(MCL_CURRENT | MCL_FUTURE): Cannot allocate memory")
    monkeypatch.setattr("pkm_common.runner.lock_memory", no_lock)
    monkeypatch.setenv(MEMORY_LOCK_ENV, "1")
    assert run_node(lambda context: Node("runner_unlocked", context=context), args=[]) == EXIT_BAD_PARAMETER
    assert "realtime profile: memory not locked: [Errno 12] mlockall(MCL_CURRENT | MCL_FUTURE)" in capfd.readouterr().err


def _policies(pid: int) -> set[tuple[int, int]]:
    """(policy, priority) of every thread of ``pid``."""
    out = set()
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            out.add((os.sched_getscheduler(int(tid)), os.sched_getparam(int(tid)).sched_priority))
        except OSError:                 # a thread that has just ended
            pass
    return out


@pytest.mark.slow
@pytest.mark.parametrize("loop_process", ["composed", "separate"])
def test_a_realtime_run_as_processes_has_its_loop_at_sched_fifo_with_memory_locked(tmp_path, realtime_loop_alone,
                                                                                   loop_process):
    """archi_demo in real time (1 kHz, Gough in the loop, recorded) with
    ``realtime_profile: true``: while it runs, every thread of the loop's process (the
    composed one, the profile's default: PROFILE["loop"]) or of each of sim_hw, the
    controller and the Gough sensor (``loop_process: separate``) is SCHED_FIFO at its
    priority and their memory is locked; the recorder keeps its own SCHED_IDLE, the
    trajectory node SCHED_OTHER, neither locked."""
    from pkm_kinematics.config import config_dir
    scenario = yaml.safe_load((config_dir() / "scenarios" / "archi_demo.yaml").read_text())
    # the sync error counter off: this 2-core VM misses bursts of 1 ms cycles (the
    # benchmark's figures), which would brake the run; the scheduling is the point here
    scenario.update({"name": "archi_demo_rt", "mode": "realtime", "realtime_profile": True, "duration_s": 2.0,
                     "program": str(config_dir() / "programs" / "archi_test_motion.nc"),
                     "plant": {**scenario["plant"], "sync_error_limit": 0}})
    if loop_process == "separate":
        scenario["loop_process"] = "separate"
    loop = ["loop"] if loop_process == "composed" else ["sim_hw", "controller", "gough_sensor"]
    path = tmp_path / "archi_demo_rt.yaml"
    path.write_text(yaml.safe_dump(scenario))
    run_dir = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "pkm_bringup.orchestrator", str(path), "--run-dir", str(run_dir),
                             "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        log = run_dir / "logs" / ("loop.log" if loop_process == "composed" else "controller.log")
        deadline = time.monotonic() + 90
        while proc.poll() is None and time.monotonic() < deadline:
            if log.exists() and "trajectory accepted" in log.read_text(errors="replace"):
                break
            time.sleep(0.05)
        pids = node_pids(run_dir)
        assert set(pids) == {"recorder", "trajectory", *loop}, pids
        seen = {name: (_policies(pid), _locked_kib(pid)) for name, pid in pids.items()}
    finally:
        out, _ = proc.communicate(timeout=120)
    assert (run_dir / "run.json").exists(), out
    run = json.loads((run_dir / "run.json").read_text())
    # the run goes to its end; in a slow phase of this VM a burst of missed deadlines may
    # trip the controller's following-error supervision (539 of 2000 missed in one
    # suite), which is the supervision working, not the scheduling failing
    tripped_by_misses = run["status"] == "tripped" and run["cause"] == "following_error" and \
        run["summaries"]["sim_hw"]["deadline_misses"] > 0
    assert proc.returncode == (3 if tripped_by_misses else 0), out
    assert run["realtime_profile"] is True and run["status"] in ("completed", "tripped"), out
    for name in loop:
        policies, locked_kib = seen[name]
        assert policies == {(os.SCHED_FIFO, PROFILE[name].priority)}, (name, policies)
        assert locked_kib > 100_000, (name, locked_kib)            # the whole process (over 1 GiB mapped)
    assert seen["recorder"][0] == {(os.SCHED_IDLE, 0)} and seen["recorder"][1] == 0
    assert seen["trajectory"][0] == {(os.SCHED_OTHER, 0)} and seen["trajectory"][1] == 0
    sim = run["summaries"]["sim_hw"]
    assert sim["steps"] == 2000 and 0 <= sim["deadline_misses"] < sim["steps"]
