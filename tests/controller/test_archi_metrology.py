"""ARCHI with the Gough metrology of config/machines/archi.yaml (docs/archi_metrology.md):
the MoM3 Gough on the nacelle covers the ARCHI test motion (struts inside their travel,
the DKM recovers the tool pose to the scale resolution) and the workspace box; closed
loop without ROS, sensor_space / measured_space keep the tool on the reference under
a cutting load that deflects the structure, where encoder-based computed_torque shows
the deflection (MoM3 §7 on ARCHI)."""

import math
from pathlib import Path

import numpy as np
import pytest

from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_kinematics.task_space import PLANAR
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_trajectory.planner import Limits, plan_with_blending
from pkm_trajectory.program import gcode_segments
from pkm_controller.closed_loop import run
from pkm_controller.config import ControllerConfig
from pkm_controller.laws import tool_pose_floats
from pkm_controller.reference import Reference

ARCHI = load_machine("archi")
MET = ARCHI.metrology
ROOT = Path(__file__).resolve().parents[2]
HOME = ARCHI.model.home.tolist()
LIMITS = Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0))   # as test_controller.py
CONTROL_LIMIT_N = 2000.0
HOLD_S = 0.3                      # hold under load before the motion: the load transient settles
COMPLIANCE = (5e-7, 5e-7, 2e-6)   # m/N, m/N, rad/(N m): 50 um under the 100 N load
LOAD = [100.0, 0.0, 0.0]          # constant cutting force along x (N, N, N m)


@pytest.fixture(scope="module")
def motion():
    """config/programs/archi_test_motion.nc planned as in test_controller.py (1 kHz):
    x 1.0 -> 1.1 m, y -0.4 -> -0.35 m, theta 45 -> 90 deg and back, 4.66 s."""
    program = (ROOT / "config" / "programs" / "archi_test_motion.nc").read_text()
    return plan_with_blending(gcode_segments(program, PLANAR, HOME), LIMITS, 0.0, 1000.0, translation_axes=2)


def _rotation(pose) -> np.ndarray:
    return np.array(tool_pose_floats(pose, True)[1]).reshape(3, 3)


def _plate_poses(sensor, poses):
    """Plate poses in the Gough base frame (through the configured mount)."""
    plates = [sensor.plate_pose(tool_pose_floats(x, True)[0], _rotation(x)) for x in poses]
    return np.array([p for p, _ in plates]), np.array([r for _, r in plates])


def test_the_metrology_section_and_its_mount_load():
    """At the ARCHI home (x 1.0, y -0.4, theta 45 deg) the plate is 25 mm off the base
    axis, 0.68 m above the base and twisted -22.5 deg (plate turned -67.5 deg on the tool)."""
    assert MET is not None and MET.encoder_resolution_m == 1e-6
    p, r = GoughSensorModel(MET).plate_pose([HOME[0], HOME[1], 0.0], _rotation(HOME))
    np.testing.assert_allclose(p, [0.0, 0.025, 0.68], atol=1e-12)
    assert math.degrees(math.atan2(r[1, 0], r[0, 0])) == pytest.approx(-22.5)
    assert r[2, 2] == pytest.approx(1.0)


def test_struts_and_estimate_over_the_test_motion(motion):
    """Every 5th sample of the planned motion: true struts 0.713-0.824 m, at least 50 mm
    inside the travel [0.634, 1.080] m; cond(J_h^-1) <= 45 (measured 44.9); the warm
    DKM (nominal geometry, 1 um readings) converges in <= 4 iterations and recovers the
    tool within 1.4 um in x-y (bound 2.5 um: half the 4.6 um worst-case resolution for
    +-1 um, plus margin), 17 urad in theta, and stays in the machine plane."""
    sensor = GoughSensorModel(MET)
    poses = np.asarray(motion.position)[::5]
    lo, hi = MET.platform.strut_limits
    lengths, errors = [], []
    for x in poses:
        p, r = tool_pose_floats(x, True)
        rot = _rotation(x)
        lengths.append(sensor.true_lengths(p, rot))
        position, rotation, result = sensor.estimate(sensor.measure(p, rot))
        assert result.converged, result.reason
        assert result.iterations <= 4
        theta = math.atan2(rotation[1, 0], rotation[0, 0])
        errors.append([math.hypot(position[0] - x[0], position[1] - x[1]),
                       abs(math.remainder(theta - x[2], 2.0 * math.pi)), abs(position[2]),
                       math.hypot(rotation[2, 0], rotation[2, 1])])
    lengths, errors = np.array(lengths), np.array(errors)
    assert lengths.min() > lo + 0.05 and lengths.max() < hi - 0.05, (lengths.min(), lengths.max())
    assert lengths.min() == pytest.approx(0.7133, abs=1e-3) and lengths.max() == pytest.approx(0.8237, abs=1e-3)
    worst = errors.max(axis=0)
    assert worst[0] < 2.5e-6 and worst[1] < 40e-6 and worst[2] < 2e-6 and worst[3] < 40e-6, worst
    positions, rotations = _plate_poses(sensor, poses)
    assert np.linalg.cond(MET.platform.inverse_jacobian_batch(positions, rotations)).max() < 46.0


def test_struts_over_the_workspace_box():
    """The trajectory-check workspace (x 0.6-1.4, y -0.6..-0.25 m) for theta 45-90 deg:
    struts 0.680-1.029 m (at least 40 mm inside the travel), cond(J_h^-1) <= 61.1."""
    xs, ys, ts = np.linspace(0.6, 1.4, 9), np.linspace(-0.6, -0.25, 5), np.radians(np.linspace(45.0, 90.0, 5))
    poses = np.stack(np.meshgrid(xs, ys, ts, indexing="ij"), axis=-1).reshape(-1, 3)
    positions, rotations = _plate_poses(GoughSensorModel(MET), poses)
    lengths = MET.platform.strut_lengths_batch(positions, rotations)
    lo, hi = MET.platform.strut_limits
    assert lengths.min() > lo + 0.04 and lengths.max() < hi - 0.04, (lengths.min(), lengths.max())
    assert np.linalg.cond(MET.platform.inverse_jacobian_batch(positions, rotations)).max() < 62.0


# ------------------------------------------------------------ closed loop
def _loaded_run(motion, strategy):
    """HOLD_S at home, then the test motion, then 0.2 s: plant with COMPLIANCE under
    LOAD from the first cycle, inf-norm distribution, the true (seed 0, calibrated)
    sensor measuring the deflected tool."""
    n = len(motion.time_s)
    reference = Reference(np.concatenate([[0.0], np.asarray(motion.time_s) + HOLD_S]),
                          np.vstack([np.asarray(motion.position)[:1], motion.position]),
                          np.vstack([np.zeros((1, 3)), motion.velocity]),
                          np.vstack([np.zeros((1, 3)), motion.acceleration]))
    plant = Plant(ARCHI, PlantParameters(force_limit_n=CONTROL_LIMIT_N, compliance=COMPLIANCE))
    config = ControllerConfig(strategy=strategy, distribution="inf_norm", force_limit_n=CONTROL_LIMIT_N)
    steps = int(HOLD_S * 1000) + n + 200
    core, log = run(ARCHI, config, plant, steps, reference=reference, sensor=GoughSensorModel(MET),
                    load=lambda t: LOAD)
    assert not core.stopped, core.stop_reason
    error = log.tool_error(True)
    theta = np.abs(np.asarray(log.reference)[:, 2] - np.asarray(log.tool)[:, 2])
    moving = slice(int(HOLD_S * 1000), int(HOLD_S * 1000) + n)
    return {"max": error[moving].max(), "mean": error[moving].mean(), "end": error[-100:].max(),
            "theta_end": theta[-100:].max()}


@pytest.fixture(scope="module")
def encoder_run(motion):
    return _loaded_run(motion, "computed_torque")


def test_computed_torque_shows_the_deflection(encoder_run):
    """Encoders cannot see the compliance: 0.5 um/N x 100 N = 50 um all along (measured:
    mean 50.05 um, 60.2 um peak during the motion with the tracking lag, 50.07 um at rest)."""
    assert encoder_run["end"] == pytest.approx(COMPLIANCE[0] * LOAD[0], rel=0.05)
    assert encoder_run["mean"] == pytest.approx(COMPLIANCE[0] * LOAD[0], rel=0.05)


@pytest.mark.parametrize("strategy", ["sensor_space", "measured_space"])
def test_the_metrology_keeps_the_tool_on_the_reference_under_load(motion, encoder_run, strategy):
    """Measured (both strategies): mean 0.57 um over the motion, 11.2 um peak (the
    dynamic lag at the accelerations; the same without load), 1.2 um and 16 urad at rest
    after the motion, against 50 um for computed_torque."""
    errors = _loaded_run(motion, strategy)
    assert errors["mean"] < 1.5e-6 and errors["mean"] < 0.05 * encoder_run["mean"], errors
    assert errors["max"] < 15e-6 and errors["max"] < 0.3 * encoder_run["max"], errors
    assert errors["end"] < 2e-6, errors
    assert errors["theta_end"] < 40e-6, errors
