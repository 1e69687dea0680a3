"""The calibration run's dwells (recorded.dwells on per-step arrays made here) and the
calibrated machine file (machine_files): written in the machine's own words, it gives
the plant's true geometry (pkm_sim_hw.plant.true_machine, a second implementation of
the same errors) to the controller."""

import numpy as np
import pytest

from pkm_calibration.machine_files import calibrated_path, calibrated_rail_machine, write_machine_file
from pkm_calibration.recorded import dwells
from pkm_calibration.self_calibration import PlanarRailErrorModel
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError
from pkm_kinematics.rotations import quaternion_from_rotation, rotation_about_z
from pkm_kinematics.task_space import PLANAR
from pkm_sim_hw.plant import true_machine


def steps_with_dwells(poses, hold_s, move_s, dt=0.001, noise=0.0, seed=0):
    """Per-step arrays: the reference ramps between ``poses`` and holds each for
    ``hold_s``; the encoders read pose index + noise (a stand-in for the machine)."""
    rng = np.random.default_rng(seed)
    ref, q = [], []
    previous = poses[0]
    for k, pose in enumerate(poses):
        for s in np.linspace(0.0, 1.0, int(move_s / dt), endpoint=False):
            ref.append(previous + s * (pose - previous))
            q.append(np.full(4, np.nan if s < 0.5 else 0.5))
        for _ in range(int(hold_s / dt)):
            ref.append(pose)
            q.append(np.full(4, float(k)) + noise * rng.standard_normal(4))
        previous = pose
    ref = np.array(ref)
    quats = np.array([quaternion_from_rotation(rotation_about_z(th)) for th in ref[:, 2]])
    return {"t_s": dt * np.arange(len(ref)), "q": np.array(q), "ref_orientation": quats,
            "ref_position": np.column_stack((ref[:, :2], np.zeros(len(ref))))}


def test_the_dwells_are_found_and_averaged_over_their_settled_part():
    poses = np.array([[1.0, -0.4, 0.5], [1.2, -0.3, -1.0], [0.8, -0.5, 2.0]])
    steps = steps_with_dwells(poses, hold_s=0.3, move_s=0.2, noise=1e-6)
    found = dwells(steps, PLANAR, min_dwell_s=0.2)
    assert len(found) == 3, [(d.start_s, d.end_s) for d in found]
    for k, d in enumerate(found):
        assert np.allclose(d.pose, poses[k], atol=1e-12), (d.pose, poses[k])
        # the first: held before its move too
        assert np.abs(d.readings - k).max() < 1e-6 and d.samples == (250 if k == 0 else 150), (d.readings, d.samples)
        assert 0.5e-6 < d.spread.mean() < 1.5e-6, d.spread
    assert len(dwells(steps, PLANAR, min_dwell_s=0.35)) == 1      # the first: 0.3 s held at the start too
    with pytest.raises(FieldError, match="settled"):
        dwells(steps, PLANAR, settled=0.0)


def test_the_calibrated_file_gives_the_plants_true_geometry(tmp_path):
    config = load_machine("archi")
    model = PlanarRailErrorModel(config.model)
    theta = np.zeros(model.size)
    theta[model.names.index("length.q3")] = 0.02            # the plant's link_length_errors [0, 0, 0.02, 0]
    theta[model.names.index("zero.q2")] = -0.003             # and its rail_offset_errors_m [0, -0.003, 0, 0]
    data = calibrated_rail_machine(config, model.names, theta, np.full(model.size, 1e-7), {"label": "t"})
    path = write_machine_file(calibrated_path(tmp_path / "archi.yaml"), data, "a test")
    assert path.name == "archi.calibrated.yaml" and path.read_text().startswith("# a test\n")
    calibrated = load_machine(path)
    truth = true_machine(config.model, (0.0, 0.0, 0.02, 0.0), (0.0, -0.003, 0.0, 0.0))
    poses = config.model.workspace_grid(5, 5)
    q_cal, ok_cal = calibrated.model.inverse_kinematics_batch(poses)
    q_true, ok_true = truth.inverse_kinematics_batch(poses)
    assert ok_cal.all() and ok_true.all()
    assert np.abs(q_cal - q_true).max() < 1e-12, np.abs(q_cal - q_true).max()
    assert calibrated.model_label == "archi (calibrated: t)"
    assert calibrated.data["calibration"]["parameters"]["length.q3"] == {"value": 0.02, "std": 1e-7}
    data["legs"][0]["link_length"] = -1.0
    with pytest.raises(ValueError, match="link_length"):
        write_machine_file(tmp_path / "bad.yaml", data)
    assert not (tmp_path / "bad.yaml").exists()


def test_a_strut_machine_as_built_is_the_error_models_machine_in_the_files_unit(tmp_path):
    """genhexkins (inches): the as-built file's struts are StrutErrorModel.machine_for
    of its truth (a second path to the same geometry); the gauge is the same names
    whatever generic poses it is found from."""
    from pkm_calibration.as_built import as_built_struts, strut_gauge
    from pkm_calibration.poses import candidate_poses
    from pkm_calibration.strut_errors import StrutErrorModel
    config = load_machine("genhexkins")
    model = StrutErrorModel(config.model, (0.0, 0.0, -0.05))
    gauges = {strut_gauge(model, config.model.inverse_kinematics_batch(candidate_poses(config.model, 40, seed))[0])
              for seed in (1, 2)}
    assert len(gauges) == 1 and len(next(iter(gauges))) == 9, gauges
    held = next(iter(gauges))
    data, truth, scales = as_built_struts(config, model, held, seed=7)
    assert all(truth[model.names.index(name)] == 0.0 for name in held)
    assert scales == [truth[model.names.index(f"scale.{leg}")] for leg in config.model.leg_names]
    built = load_machine(write_machine_file(tmp_path / "built.yaml", data)).model
    expected = model.machine_for(truth)
    assert np.abs(built.base_joints - expected.base_joints).max() < 1e-12
    assert np.abs(built.platform_joints - expected.platform_joints).max() < 1e-12
    assert 1e-4 < np.abs(built.base_joints - config.model.base_joints).max() < 3e-3


def test_a_calibrated_strut_file_carries_its_encoders_zero_and_scale_as_tables(tmp_path):
    """l = q + z + s q of the identification, as the controller will apply it
    (pkm_kinematics.compensation) over the strut's travel."""
    from pkm_calibration.machine_files import calibrated_strut_machine
    from pkm_calibration.strut_errors import StrutErrorModel
    from pkm_kinematics.compensation import compensation_of
    config = load_machine("genhexkins")
    model = StrutErrorModel(config.model)
    theta = np.random.default_rng(8).normal(0.0, 2e-4, model.size)
    path = write_machine_file(tmp_path / "g.yaml", calibrated_strut_machine(config, model.names, theta,
                                                                             np.zeros(model.size), {"label": "g"}))
    comp = compensation_of(load_machine(path))
    q = np.linspace(config.model.joint_lower, config.model.joint_upper, 7)
    expected = model.lengths(theta, q)
    got = np.array([comp.positions(row) for row in q])
    assert np.abs(got - expected).max() < 1e-12, np.abs(got - expected).max()
