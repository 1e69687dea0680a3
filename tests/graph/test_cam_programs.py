"""Part programs as CAM post-processors for LinuxCNC write them (config/programs/cam_*.nc:
work offsets, tool changes with their lengths from config/tools/tool.tbl, spindle and
coolant, arcs in three planes, drilling cycles, a tilt about the tool tip) planned and
run in the graph on the Orthoglide and the genhexkins hexapod: tracked, their events on
program/events in program order, and the hexapod's true tool tip (its true pose and the
tool's 50 mm) held at the programmed point while the platform turns about it."""

import json

import numpy as np
import pytest

from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
from pkm_runs.replay import recorded_messages

TOOL_M = 0.05            # T1's length (config/tools/tool.tbl)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("cam")
    return {name: (root / name, run_scenario(load_scenario(name), root / name, in_process=True, progress=False))
            for name in ("orthoglide_cam", "hexapod_cam")}


def events(run_dir) -> list:
    records = [json.loads(m.data) for _, _, m in recorded_messages(run_dir / "bag", "/pkm", ("program/events",))]
    assert len(records) == 1, records
    return records[0]["events"]


@pytest.mark.parametrize("name, rms_um", [("orthoglide_cam", 30.0), ("hexapod_cam", 10.0)])
def test_cam_programs_run_tracked(runs, name, rms_um):
    run_dir, result = runs[name]
    assert result["status"] == "completed", result["error"]
    tracking = result["metrics"]["tracking_error"]
    assert tracking["rms_m"] < rms_um * 1e-6, tracking
    assert result["metrics"]["messages"]["lost_total"] == 0


def test_the_orthoglide_program_events_in_order_at_their_times(runs):
    run_dir, result = runs["orthoglide_cam"]
    found = events(run_dir)
    assert [(e["line"], e["name"]) for e in found] == [
        (10, "tool_change"), (11, "spindle"), (13, "coolant"), (25, "coolant"), (26, "spindle"),
        (28, "tool_change"), (29, "spindle"), (30, "coolant"), (38, "coolant"), (39, "spindle")]
    assert [e.get("tool") for e in found if e["name"] == "tool_change"] == [1, 2]
    assert [e["rpm"] for e in found if e["name"] == "spindle"] == [12000.0, 12000.0, 8000.0, 8000.0]
    times = [e["t_s"] for e in found]
    assert times == sorted(times) and 5.0 < times[5] < times[-1] < result["summaries"]["sim_hw"]["sim_time_s"]


def quaternion_matrix(x, y, z, w) -> np.ndarray:
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_the_hexapod_turns_about_the_true_tool_tip(runs):
    """cam_hexapod.nc tilts A 5 deg, B -5 deg and back at X0 Y20 Z0 (G54: machine Z 458
    mm): the true tip stays within tracking of that point while the platform moves mm."""
    run_dir, _ = runs["hexapod_cam"]
    tips, origins = [], []
    for _, _, msg in recorded_messages(run_dir / "bag", "/pkm", ("platform/true_pose",)):
        q = msg.pose.orientation
        rotation = quaternion_matrix(q.x, q.y, q.z, q.w)
        if np.degrees(np.arccos(min(1.0, rotation[2, 2]))) < 1.0:      # the tilt: the tool more than 1 deg off z
            continue
        p = np.array([msg.pose.position.x, msg.pose.position.y, msg.pose.position.z])
        tips.append(p - rotation @ [0.0, 0.0, TOOL_M])
        origins.append(p)
    assert len(tips) > 500, len(tips)
    deviation = np.linalg.norm(np.array(tips) - [0.0, 0.02, 0.458], axis=1).max()
    travel = np.ptp(np.array(origins), axis=0).max()
    assert deviation < 30e-6, deviation
    assert travel > 2e-3, travel


def drive_forces(run_dir) -> tuple[np.ndarray, np.ndarray]:
    stamps, forces = [], []
    for _, _, c in recorded_messages(run_dir / "bag", "/pkm", ("drives/command",)):
        stamps.append(c.header.stamp.sec + 1e-9 * c.header.stamp.nanosec)
        forces.append(list(c.effort))
    return np.array(stamps), np.array(forces)


def test_a_spindle_load_the_scenario_models_follows_the_programs_spindle(runs, tmp_path):
    """orthoglide_cam with spindle_load (40 N down at 12,000 rpm, scaled by S): the drives
    push back with it while the spindle turns (T1 at 12,000 rpm, T2 at 8,000), not after
    M5; the same run without it is the reference."""
    spec = {"wrench": [0.0, 0.0, -40.0], "ramp_s": 0.05, "reference_rpm": 12000}
    loaded = run_scenario(load_scenario("orthoglide_cam", {"spindle_load": spec}), tmp_path / "loaded",
                          in_process=True, progress=False)
    assert loaded["status"] == "completed", loaded["error"]
    t, with_load = drive_forces(tmp_path / "loaded")
    t0, without = drive_forces(runs["orthoglide_cam"][0])
    assert np.array_equal(t - t[0], t0 - t0[0])
    push = np.linalg.norm(with_load - without, axis=1)
    rel = t - t[0]

    def mean(lo, hi):
        return float(push[(rel > lo) & (rel < hi)].mean())
    t1, t2, after = mean(1.0, 16.5), mean(17.5, 26.3), mean(26.6, 26.67)
    assert 30.0 < t1 < 60.0 and t2 == pytest.approx(t1 * 8000 / 12000, rel=0.1) and after < 0.1 * t1, (t1, t2, after)
