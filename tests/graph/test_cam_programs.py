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
