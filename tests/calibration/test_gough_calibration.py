"""A machine on rails calibrated with its Gough metrology strut by strut
(gough_errors.GoughStrutRailModel): the struts' Jacobians against central differences
(MoM3's Delta, translating; ARCHI, planar); the model's strut lengths against the
sensor's own (pkm_gough_sensor's GoughSensorModel with its joints mis-calibrated: a
second implementation); what a translating platform cannot separate, named; the
machine's errors and the Gough's own recovered together from noise-free readings."""

import numpy as np
import pytest
from finite_differences import central_differences, worst_column      # tests/finite_differences.py

from pkm_calibration.gough_errors import GoughStrutRailModel, gough_joints
from pkm_calibration.identify import gauge
from pkm_calibration.machine_files import calibrated_rail_machine
from pkm_calibration.poses import candidate_poses
from pkm_calibration.self_calibration import calibrate_rails
from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics import load_machine
from pkm_kinematics.config import load_machine_data
from pkm_kinematics.errors import ConfigError, FieldError

SCALES = (1e-6, 1e-6)


def setup(name, count, seed):
    config = load_machine(name)
    base, plate = gough_joints(config.metrology)
    return config, GoughStrutRailModel(config.model, base=base, plate=plate), candidate_poses(config.model, count, seed)


def encoders(model, theta, poses):
    q, ok = model.machine_for(theta).inverse_kinematics_batch(poses)
    assert ok.all()
    return q


def rotation(model, pose):
    if not model.planar:
        return np.eye(3)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("name", ["mom3", "archi"])
def test_the_struts_jacobians_are_their_derivatives(name):
    _, model, poses = setup(name, 5, 1)
    theta = np.random.default_rng(2).normal(0.0, 1e-3, model.size)
    y_pose, y_theta = model.point_jacobian(theta, poses)
    error, j = worst_column(central_differences(lambda t: model.points(t, poses), theta), y_theta)
    assert error < 1e-7, model.names[j]
    error, j = worst_column(central_differences(lambda x: model.points(theta, x), poses), y_pose)
    assert error < 1e-7, j


@pytest.mark.parametrize("name", ["mom3", "archi"])
def test_the_struts_are_what_the_mis_calibrated_sensor_reads(name):
    config, model, poses = setup(name, 6, 3)
    sensor = GoughSensorModel(config.metrology, 0.0, seed=7, calibration_error_m=5e-4, resolution_m=1e-12)
    m = config.metrology
    theta = np.zeros(model.size)
    g = model.gough_columns
    theta[g:g + 18] = ((sensor.true_platform.base_points - sensor.nominal.base_points) @ np.asarray(m.base_rotation).T
                       ).ravel()
    theta[g + 18:] = ((sensor.true_platform.plate_points - sensor.nominal.plate_points)
                      @ np.asarray(m.plate_rotation_in_tool).T).ravel()
    assert np.abs(theta[g:]).max() > 1e-4                          # the sensor's joints are off
    p, _ = model._pose(poses)
    read = np.array([sensor.measure(p[i], rotation(model, poses[i])) for i in range(len(poses))])
    assert np.abs(model.points(theta, poses) - read).max() < 1e-9
    assert np.abs(model.points(np.zeros(model.size), poses) - read).max() > 1e-4


def test_a_translating_platform_cannot_separate_plate_from_base_joints_and_the_datum_is_held():
    _, model, poses = setup("mom3", 40, 3)
    q0 = encoders(model, np.zeros(model.size), poses)
    held = gauge(model.parameter_jacobian(poses, q0, SCALES), model.names)
    plate = [n for n in model.names if n.startswith("gough.plate.")]
    assert set(plate) <= set(held), held                           # only C_j - G_j enters without rotation
    others = [n for n in held if n not in plate]
    # the Delta's three b.z (as with the Gough's pose) and the datum: one shift of the
    # Gough's base against the platform's joints, and one more the motions cannot see
    assert others == ["b.z.q1", "b.z.q2", "b.z.q3", "gough.base.5.y", "gough.base.6.x", "gough.base.6.y",
                      "gough.base.6.z"], others
    assert len(model.identifiability(poses, q0, SCALES).identified) == model.size - len(held)


def test_the_machine_and_the_goughs_own_errors_recovered_from_noise_free_readings():
    _, model, poses = setup("mom3", 30, 5)
    q0 = encoders(model, np.zeros(model.size), poses)
    held = gauge(model.parameter_jacobian(poses, q0, SCALES), model.names)
    truth = np.random.default_rng(6).normal(0.0, 5e-4, model.size)
    truth[[model.names.index(n) for n in held]] = 0.0
    q, struts = encoders(model, truth, poses), model.points(truth, poses)
    result = calibrate_rails(model, q, poses + 1e-3, struts, held=held)
    assert result.misfit_before_m > 1e-4 and result.misfit_after_m < 1e-12, (result.misfit_before_m,
                                                                             result.misfit_after_m)
    assert np.abs(result.theta - truth).max() < 1e-9, np.abs(result.theta - truth).max()


def test_a_gough_without_its_joints_is_refused_naming_the_metrology():
    config = load_machine("mom3")
    with pytest.raises(FieldError) as info:
        GoughStrutRailModel(config.model, base=np.zeros((5, 3)), plate=np.zeros((6, 3)))
    assert info.value.name == "metrology"


def test_the_goughs_identified_joints_go_into_its_metrology_section_and_a_wild_one_is_refused():
    config, model, _ = setup("mom3", 1, 0)
    theta = np.zeros(model.size)
    g = model.gough_columns
    theta[g:g + 3] = [1e-4, -2e-4, 3e-4]                               # strut 1's base joint (world)
    theta[g + 33:g + 36] = [5e-5, 0.0, -5e-5]                         # strut 6's plate joint (tool frame)
    data = calibrated_rail_machine(config, model.names, theta, np.zeros(model.size), {"label": "t"})
    calibrated = load_machine_data(data, "mom3.calibrated.yaml")
    base, plate = gough_joints(calibrated.metrology)
    nominal_base, nominal_plate = gough_joints(config.metrology)
    assert np.abs(base - nominal_base - theta[g:g + 18].reshape(6, 3)).max() < 1e-12
    assert np.abs(plate - nominal_plate - theta[g + 18:].reshape(6, 3)).max() < 1e-12
    data["metrology"]["geometry"]["joint_offsets"]["base"][2] = [0.0, 0.02, 0.0]
    with pytest.raises(ConfigError) as info:
        load_machine_data(data, "mom3.calibrated.yaml")
    assert info.value.name.endswith("metrology.geometry.joint_offsets.base[2]"), info.value.name
