"""Gough metrology model (MoM3 §4.3, §5, §6.3): quantised strut readings of a tool pose
and the pose back from them.

References independent of the code under test: strut lengths from world-frame joint
centres built with 4 x 4 homogeneous transforms, the per-pose worst case of the
linearised model |dx| <= max over dl in {+-res/2}^6 of |J_h dl| (MoM3 eq. 1), and
``pkm_kinematics.analysis.gough_resolution`` (MoM3 §5.5, eq. 20-21).
"""

import dataclasses
import itertools
import math

import numpy as np
import pytest

from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_kinematics.analysis import gough_resolution
from pkm_kinematics.rotations import exp_so3, log_so3, rotation_from_rpy

MET = load_machine('mom3').metrology
RES = MET.encoder_resolution_m
SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=6)))


def homogeneous(p, rot):
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = p
    return t


def tool_from_plate(met, p_bp, r_bp):
    """T_world_tool = T_world_base T_base_plate T_tool_plate^-1 (matrices, not the model)."""
    t = (homogeneous(met.base_position, met.base_rotation) @ homogeneous(p_bp, r_bp)
         @ np.linalg.inv(homogeneous(met.plate_position_in_tool, met.plate_rotation_in_tool)))
    return t[:3, 3], t[:3, :3]


def world_lengths(met, base_points, plate_points, p_t, r_t):
    """|B_i - A_i| with both joint centres in world coordinates."""
    t_wb = homogeneous(met.base_position, met.base_rotation)
    t_wp = homogeneous(p_t, r_t) @ homogeneous(met.plate_position_in_tool, met.plate_rotation_in_tool)
    a = (t_wb @ np.c_[base_points, np.ones(6)].T).T[:, :3]
    b = (t_wp @ np.c_[plate_points, np.ones(6)].T).T[:, :3]
    return np.linalg.norm(b - a, axis=1)


def random_plate_poses(met, n, seed, tilt=2e-3):
    """Plate poses in the Gough base frame: positions over the metrology cube, small rotations."""
    rng = np.random.default_rng(seed)
    half = met.workspace_size_m / 2.0
    positions = met.workspace_center + rng.uniform(-half, half, (n, 3))
    rotations = [exp_so3(rng.uniform(-tilt, tilt, 3)) for _ in range(n)]
    return positions, rotations


def worst_case(platform, p, rot, eps):
    """MoM3 eq. 1: the largest |dp_h| and |dr_h| over strut errors in {-eps, +eps}^6."""
    dx = SIGNS * eps @ platform.jacobian(p, rot).T
    return np.linalg.norm(dx[:, :3], axis=1).max(), np.linalg.norm(dx[:, 3:], axis=1).max()


def mounted(**mount):
    return dataclasses.replace(MET, **mount)


# ------------------------------------------------------------- quantisation
def test_readings_are_quantised_to_the_resolution():
    model = GoughSensorModel(MET)
    assert model.resolution_m == RES == 1e-6          # MoM3 §4.3: 1 um linear scales
    positions, rotations = random_plate_poses(MET, 200, seed=1)
    for p_bp, r_bp in zip(positions, rotations):
        p_t, r_t = tool_from_plate(MET, p_bp, r_bp)
        measured = model.measure(p_t, r_t)
        exact = world_lengths(MET, MET.platform.base_points, MET.platform.plate_points, p_t, r_t)
        counts = measured / RES
        np.testing.assert_allclose(counts, np.round(counts), rtol=0, atol=1e-6)
        assert np.abs(measured - exact).max() <= RES / 2 + 1e-12


def test_coarser_resolution_is_honoured():
    model = GoughSensorModel(MET, resolution_m=1e-4)
    p_t, r_t = tool_from_plate(MET, MET.platform.home_position + [0.01, -0.02, 0.03], np.eye(3))
    measured = model.measure(p_t, r_t)
    np.testing.assert_allclose(measured / 1e-4, np.round(measured / 1e-4), atol=1e-6)
    assert np.abs(measured - model.true_lengths(p_t, r_t)).max() <= 0.5e-4 + 1e-12


# --------------------------------------------------------------- round trip
def test_round_trip_within_the_mom3_worst_case_resolution():
    """Quantisation errors are at most res/2 per strut, so the plate position error is
    bounded by the linearised worst case for res/2 at that pose, and by MoM3's
    worst-case position resolution (for +-res) over the workspace."""
    model = GoughSensorModel(MET)
    bound = gough_resolution(MET.platform, RES, MET.tool_box, MET.workspace_center, MET.workspace_size_m)
    assert 5e-6 < bound.position_m < 7e-6             # MoM3 §5.6: about 6 um
    positions, rotations = random_plate_poses(MET, 300, seed=2)
    errors = []
    for p_bp, r_bp in zip(positions, rotations):
        p_t, r_t = tool_from_plate(MET, p_bp, r_bp)
        est_p, est_r, result = model.estimate(model.measure(p_t, r_t))
        assert result.converged, result.reason
        # back to the plate, with the test's own transforms
        t_bp = (np.linalg.inv(homogeneous(MET.base_position, MET.base_rotation)) @ homogeneous(est_p, est_r)
                @ homogeneous(MET.plate_position_in_tool, MET.plate_rotation_in_tool))
        dp = np.linalg.norm(t_bp[:3, 3] - p_bp)
        dr = np.linalg.norm(log_so3(t_bp[:3, :3] @ r_bp.T))
        # each strut is off by at most res/2 (quantisation) + the DKM residual tolerance
        pos_bound, rot_bound = worst_case(MET.platform, p_bp, r_bp, RES / 2 + model.dkm_tol_m)
        assert dp <= pos_bound * 1.001
        assert dr <= rot_bound * 1.001
        assert dp <= bound.position_m
        assert dr <= bound.orientation_rad
        # the tool (0.1 m above the plate) also moves with the plate's rotation error
        assert np.linalg.norm(est_p - p_t) <= bound.position_m + 0.1 * bound.orientation_rad
        errors.append(dp)
    assert np.median(errors) > 1e-8                   # quantisation is really there


def test_calibration_error_grows_the_error_but_the_dkm_converges():
    positions, rotations = random_plate_poses(MET, 100, seed=3)

    def errors(model):
        out = []
        for p_bp, r_bp in zip(positions, rotations):
            p_t, r_t = tool_from_plate(MET, p_bp, r_bp)
            est_p, _, result = model.estimate(model.measure(p_t, r_t))
            assert result.converged, result.reason
            out.append(np.linalg.norm(est_p - p_t))
        return np.array(out)

    nominal = errors(GoughSensorModel(MET))
    miscalibrated = GoughSensorModel(MET, calibration_error_m=1e-4, seed=7)
    shifted = np.abs(miscalibrated.true_platform.base_points - MET.platform.base_points)
    assert 1e-6 < shifted.max() < 1e-3                # joint centres moved by ~0.1 mm
    wrong = errors(miscalibrated)
    assert np.median(wrong) > 10 * np.median(nominal)
    assert wrong.max() > gough_resolution(
        MET.platform, RES, MET.tool_box, MET.workspace_center, MET.workspace_size_m).position_m


def test_calibration_error_is_reproducible_per_seed():
    a = GoughSensorModel(MET, calibration_error_m=1e-4, seed=3)
    b = GoughSensorModel(MET, calibration_error_m=1e-4, seed=3, noise_std_m=1e-6)
    c = GoughSensorModel(MET, calibration_error_m=1e-4, seed=4)
    np.testing.assert_array_equal(a.true_platform.plate_points, b.true_platform.plate_points)
    assert not np.allclose(a.true_platform.plate_points, c.true_platform.plate_points)
    exact = GoughSensorModel(MET, seed=3)
    np.testing.assert_array_equal(exact.true_platform.base_points, MET.platform.base_points)


def test_noise_statistics():
    std = 5e-6
    model = GoughSensorModel(MET, noise_std_m=std, seed=11, resolution_m=1e-9)
    positions, rotations = random_plate_poses(MET, 2000, seed=4)
    diffs = []
    for p_bp, r_bp in zip(positions, rotations):
        p_t, r_t = tool_from_plate(MET, p_bp, r_bp)
        diffs.append(model.measure(p_t, r_t)
                     - world_lengths(MET, MET.platform.base_points, MET.platform.plate_points, p_t, r_t))
    diffs = np.concatenate(diffs)                     # 12,000 samples
    assert abs(diffs.std() / std - 1.0) < 0.05        # sampling error of the std ~0.7 %
    assert abs(diffs.mean()) < 5 * std / math.sqrt(diffs.size)
    # same seed, same readings
    again = GoughSensorModel(MET, noise_std_m=std, seed=11, resolution_m=1e-9)
    p_t, r_t = tool_from_plate(MET, positions[0], rotations[0])
    np.testing.assert_array_equal(again.measure(p_t, r_t), GoughSensorModel(
        MET, noise_std_m=std, seed=11, resolution_m=1e-9).measure(p_t, r_t))


# ----------------------------------------------------------------- mounting
def test_identity_mounting_reproduces_the_plate_pose():
    met = mounted(base_position=np.zeros(3), base_rotation=np.eye(3),
                  plate_position_in_tool=np.zeros(3), plate_rotation_in_tool=np.eye(3))
    model = GoughSensorModel(met)
    p = met.platform.home_position + [0.04, -0.03, 0.05]
    rot = rotation_from_rpy(0.002, -0.001, 0.003)
    plate_p, plate_r = model.plate_pose(p, rot)
    np.testing.assert_allclose(plate_p, p, atol=1e-15)
    np.testing.assert_allclose(plate_r, rot, atol=1e-15)
    np.testing.assert_allclose(model.measure(p, rot), np.round(met.platform.strut_lengths(p, rot) / RES) * RES,
                               atol=1e-12)
    est_p, est_r, result = model.estimate(model.measure(p, rot))
    assert result.converged
    np.testing.assert_allclose(est_p, result.position, atol=0)
    np.testing.assert_allclose(est_r, result.rotation, atol=0)
    assert np.linalg.norm(est_p - p) <= worst_case(met.platform, p, rot, RES / 2 + model.dkm_tol_m)[0] * 1.001


def test_rotated_base_and_plate_mounting_round_trip():
    met = mounted(base_position=np.array([0.2, -0.1, 0.3]),
                  base_rotation=rotation_from_rpy(*np.radians([5.0, -3.0, 30.0])),
                  plate_position_in_tool=np.array([0.01, 0.02, -0.1]),
                  plate_rotation_in_tool=rotation_from_rpy(*np.radians([1.0, 2.0, 90.0])))
    model = GoughSensorModel(met)
    positions, rotations = random_plate_poses(met, 100, seed=5)
    for p_bp, r_bp in zip(positions, rotations):
        p_t, r_t = tool_from_plate(met, p_bp, r_bp)
        # the tool pose really is far from the plate pose in this mounting
        assert np.linalg.norm(p_t - p_bp) > 0.1
        exact = world_lengths(met, met.platform.base_points, met.platform.plate_points, p_t, r_t)
        np.testing.assert_allclose(exact, met.platform.strut_lengths(p_bp, r_bp), atol=1e-12)
        measured = model.measure(p_t, r_t)
        assert np.abs(measured - exact).max() <= RES / 2 + 1e-12
        est_p, est_r, result = model.estimate(measured)
        assert result.converged, result.reason
        plate_p, plate_r = model.plate_pose(p_t, r_t)
        np.testing.assert_allclose(plate_p, p_bp, atol=1e-12)
        np.testing.assert_allclose(plate_r, r_bp, atol=1e-12)
        pos_bound, rot_bound = worst_case(met.platform, p_bp, r_bp, RES / 2 + model.dkm_tol_m)
        assert np.linalg.norm(log_so3(est_r @ r_t.T)) <= rot_bound * 1.001
        # tool = plate + R_t (-p_tp): the lever adds |dr| |p_tp|
        lever = np.linalg.norm(met.plate_position_in_tool)
        assert np.linalg.norm(est_p - p_t) <= (pos_bound + rot_bound * lever) * 1.001


def test_a_path_stays_converged_with_few_iterations():
    """A 1 kHz stream along a circle (0.1 m/s): the warm start needs few iterations."""
    model = GoughSensorModel(MET, noise_std_m=2e-7, seed=5)
    iterations = []
    for k in range(500):
        t = k / 1000.0
        p_bp = MET.workspace_center + [0.05 * math.cos(2 * t), 0.05 * math.sin(2 * t), 0.02 * t]
        p_t, r_t = tool_from_plate(MET, p_bp, np.eye(3))
        est_p, _, result = model.estimate(model.measure(p_t, r_t))
        assert result.converged, result.reason
        assert np.linalg.norm(est_p - p_t) < 2e-5
        iterations.append(result.iterations)
    assert np.mean(iterations[10:]) <= 1.5          # mostly one Newton step (tol = res / 1000)


# ----------------------------------------------------------------- failures
def test_impossible_lengths_fail_with_nan_and_a_reason():
    model = GoughSensorModel(MET)
    good = model.measure(*tool_from_plate(MET, MET.platform.home_position, np.eye(3)))
    assert model.estimate(good)[2].converged
    # inside the strut travel, but no plate pose has these lengths
    p, rot, result = model.estimate([0.64] * 5 + [1.07])
    assert not result.converged
    assert 'diverged' in result.reason or 'no convergence' in result.reason, result.reason
    assert np.isnan(p).all() and np.isnan(rot).all()
    # outside the travel: the scales cannot read there; the DKM is not tried
    p, rot, result = model.estimate([0.9, 0.9, 2.5, 0.9, 0.9, 0.9])
    assert not result.converged and result.iterations == 0
    assert 'strut3' in result.reason and 'outside the strut travel [0.634, 1.08] m' in result.reason
    assert np.isnan(p).all() and np.isnan(rot).all()
    # the next good reading is solved again (from the last good pose)
    p, _, result = model.estimate(good)
    assert result.converged and np.isfinite(p).all()


def test_a_tool_pose_far_outside_cannot_be_estimated():
    model = GoughSensorModel(MET)
    p_t, r_t = tool_from_plate(MET, [1.5, 0.0, 0.8], np.eye(3))
    p, _, result = model.estimate(model.measure(p_t, r_t))
    assert not result.converged and 'outside the strut travel' in result.reason
    assert np.isnan(p).all()


@pytest.mark.parametrize('call,field', [
    (lambda m: m.measure([0.0, math.nan, 0.9], np.eye(3)), 'tool_position'),
    (lambda m: m.measure([0.0, 0.9], np.eye(3)), 'tool_position'),
    (lambda m: m.measure([0.0, 0.0, 0.9], np.eye(3) * 1.1), 'tool_rotation: not a rotation'),
    (lambda m: m.measure([0.0, 0.0, 0.9], np.eye(2)), 'tool_rotation'),
    (lambda m: m.measure([0.0, 0.0, 0.9], np.full((3, 3), np.inf)), 'tool_rotation'),
    (lambda m: m.estimate([0.8] * 5), 'strut lengths'),
    (lambda m: m.estimate([0.8] * 5 + [math.nan]), 'strut lengths'),
])
def test_bad_inputs_name_the_field(call, field):
    with pytest.raises(ValueError, match=field):
        call(GoughSensorModel(MET))


@pytest.mark.parametrize('kwargs,field', [
    ({'noise_std_m': -1e-6}, r'noise_std_m: must be in \[0, inf\) m'),
    ({'noise_std_m': math.nan}, 'noise_std_m'),
    ({'calibration_error_m': -1.0}, 'calibration_error_m'),
    ({'resolution_m': 0.0}, r'resolution_m: must be in \(0, 0.001\] m'),
    ({'resolution_m': 0.01}, 'resolution_m'),
    ({'seed': -1}, 'seed'),
    ({'seed': 1.5}, 'seed'),
])
def test_bad_parameters_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        GoughSensorModel(MET, **kwargs)


def test_a_machine_without_metrology_is_refused():
    with pytest.raises(ValueError, match='metrology'):
        GoughSensorModel(load_machine('sliding_star').metrology)
