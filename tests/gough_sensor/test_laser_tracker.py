"""The laser tracker: its reading against the frame transform written out here, its
noise's statistics, bad parameters named; in the graph (ARCHI, one second in one
process), instrument/laser recorded at every step, each reading the plant's true tool
point within the stated noise."""

import numpy as np
import pytest

from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import ScenarioError, load_scenario
from pkm_gough_sensor.laser import LaserTracker
from pkm_kinematics.errors import FieldError
from pkm_kinematics.rotations import rotation_from_quaternion
from pkm_runs.report_data import load_run


def rz(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_the_reading_is_the_tool_point_in_the_trackers_frame():
    tracker = LaserTracker(tool=(0.1, 0.0, -0.05), frame_position=(2.0, 1.0, 0.5), frame_rpy_deg=(0.0, 0.0, 90.0))
    p, rot = np.array([1.0, -0.4, 0.0]), rz(30.0)
    world = p + rot @ [0.1, 0.0, -0.05]
    expected = rz(90.0).T @ (world - [2.0, 1.0, 0.5])          # R_T^T (p + R t - p_T)
    assert np.allclose(tracker.measure(p, rot), expected, atol=1e-15)
    noisy = LaserTracker(tool=(0.1, 0.0, -0.05), sigma_m=2e-6, seed=3)
    errors = np.array([noisy.measure(p, rot) - (p + rot @ [0.1, 0.0, -0.05]) for _ in range(4000)])
    assert np.abs(errors.mean(axis=0)).max() < 5 * 2e-6 / np.sqrt(4000), errors.mean(axis=0)
    assert np.allclose(errors.std(axis=0), 2e-6, rtol=0.05), errors.std(axis=0)
    with pytest.raises(FieldError, match=r"sigma_m: must be in \[0, 0.001\] m, got 0.1"):
        LaserTracker(sigma_m=0.1)


def test_the_graph_records_the_tracker_at_every_step(tmp_path):
    s = load_scenario("archi_fig12", {"laser_tracker": {"sigma_m": 1e-6, "tool": [0.1, 0.0, 0.0]},
                                      "controller": {"strategy": "decentralized_projected"}})
    run = run_scenario(s, tmp_path / "run", in_process=True, progress=False, report=False)
    assert run["status"] == "completed" and run["lost"]["/pkm/instrument/laser"] == 0, (run["status"], run["lost"])
    steps = load_run(tmp_path / "run").steps
    laser, true = steps.rows["instrument"], steps.rows["true_pose"]
    assert laser.present.sum() == true.present.sum() == 1001
    point = np.array([p + rotation_from_quaternion(q) @ [0.1, 0.0, 0.0] for p, q in zip(true.position,
                                                                                         true.orientation)])
    error = laser.position - point
    assert np.abs(error).max() < 5e-6 and 0.8e-6 < error.std() < 1.2e-6, (np.abs(error).max(), error.std())
    with pytest.raises(ScenarioError, match="^laser_tracker.sigma: not a laser_tracker parameter"):
        load_scenario("archi_fig12", {"laser_tracker": {"sigma": 1e-6}})
    with pytest.raises(ScenarioError, match=r"^laser_tracker.sigma_m: must be in \[0, 0.001\] m, got 0.5"):
        load_scenario("archi_fig12", {"laser_tracker": {"sigma_m": 0.5}})     # refused at load, not at start
    assert load_scenario("archi_fig12").laser_tracker is None
