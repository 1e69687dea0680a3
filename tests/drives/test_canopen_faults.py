"""Faults through the bus, in the graph (archi_canopen in one process): each injected
drive fault (virtual_drives_node ``drive_faults``) stops the machine, the run tripped
with the fault's cause and the drive named (with its error code), detected within a
stated number of cycles, and the machine held: the true tool pose moves less than a
stated bound after the stop. The rows of the closing note's fault table."""

import numpy as np
import pytest

from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
from pkm_common.causes import plant_status
from pkm_runs.replay import recorded_messages

FAULT_S = 0.6
DT_NS = 2_000_000
# fault -> (cause, what the trip reason says, cycles from the fault to the stop at most)
FAULTS = {
    "over_current": ("drive_fault", "drive q3 (node 3) sent an emergency (EMCY): 0x2310 continuous over-current", 2),
    "following_error": ("drive_fault", "drive q3 (node 3) sent an emergency (EMCY): 0x8611 following error", 2),
    "encoder": ("drive_fault", "drive q3 (node 3) sent an emergency (EMCY): 0x7305 incremental encoder 1 broken", 2),
    "silent": ("pdo_missed", "drive q3 (node 3) sent no TPDO within 500 ms", 2),
    "local_stop": ("drive_disabled", "drive q3 (node 3) left operation enabled: quick stop active", 2),
    # wall clock: 3 heartbeat periods (0.3 s) of a loop at ~700 cycles/s
    "heartbeat_lost": ("heartbeat_lost", "drive q3 (node 3) sent no heartbeat for", 1000),
}


def _stop_stamp(run_dir) -> int:
    for _, _, msg in recorded_messages(run_dir / "bag", "/pkm", ("drives/state",)):
        if plant_status(msg.header.frame_id).stopped:
            return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    raise AssertionError("the drives never said they stopped")


def _poses(run_dir) -> dict:
    return {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec: (m.pose.position.x, m.pose.position.y)
            for _, _, m in recorded_messages(run_dir / "bag", "/pkm", ("platform/true_pose",))}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_drive_fault_through_the_bus_stops_the_machine_naming_it(fault, tmp_path):
    cause, reason, max_cycles = FAULTS[fault]
    duration = 1.2 if fault != "heartbeat_lost" else 2.0
    s = load_scenario("archi_canopen", {"duration_s": duration, "drives": {"drive_faults": f"2:{fault}:{FAULT_S}"}})
    run = run_scenario(s, tmp_path / fault, in_process=True, progress=False)
    assert run["status"] == "tripped" and run["cause"] == cause, (run["status"], run["cause"], run["trip_reason"])
    assert reason in run["trip_reason"], run["trip_reason"]
    stop = _stop_stamp(tmp_path / fault)
    cycles = (stop - round(FAULT_S * 1e9)) // DT_NS
    assert 0 < cycles <= max_cycles, cycles
    poses = _poses(tmp_path / fault)
    after = np.array([p for t, p in sorted(poses.items()) if t >= stop])
    moved = np.hypot(*(after - after[0]).T).max()
    assert moved < 1e-6, f"the tool moved {moved * 1e6:.2f} um after the stop"
    print(f"fault table: {fault}: {cause}, {cycles} cycles ({cycles * DT_NS * 1e-6:g} ms simulated), "
          f"moved {moved * 1e6:.3f} um after the stop; {run['trip_reason']}")
