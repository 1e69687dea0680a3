"""The Delta with its parallelograms as bars (pkm_kinematics.parallelogram on the
bar kernels): equal bars give the translational Delta of mom3.yaml exactly; unequal
bars (MoM3 §4.1's imperfect case, config/machines/mom3_imperfect.yaml) tilt the
platform, which the drive encoders cannot see and the Gough metrology measures.

References: the translational model (the translating RailMachine, closed forms), the bar
lengths recomputed in numpy, scipy's fsolve from another start, finite differences,
and the Gough platform's own direct kinematics."""

import numpy as np
import pytest
import yaml
from scipy.optimize import fsolve

from pkm_kinematics import ConfigError, load_machine, load_machine_data
from pkm_kinematics.config import config_dir
from pkm_kinematics.parallelogram import ParallelogramMachine, tilt_urad
from pkm_kinematics.rotations import exp_so3, log_so3

POINTS = [np.array([0.0, 0.0, 0.882]), np.array([0.12, -0.1, 0.95]), np.array([-0.14, 0.13, 0.76])]


def imperfect() -> ParallelogramMachine:
    return load_machine("mom3_imperfect").model


def bar_lengths(machine, p, rot, q):
    a = machine.bars[:, 0:3] + q[machine.bars[:, 10].astype(int)][:, None] * machine.bars[:, 3:6]
    return np.linalg.norm(p + machine.bars[:, 6:9] @ rot.T - a, axis=1)


def test_equal_bars_are_the_translational_delta():
    delta = load_machine("mom3").model
    perfect = ParallelogramMachine("perfect", delta.legs, 0.03, np.zeros((3, 2)), delta.home, delta.workspace)
    for p in POINTS:
        pose = perfect.inverse_kinematics_full(p)
        np.testing.assert_allclose(pose.rotation, np.eye(3), rtol=0, atol=1e-15)
        np.testing.assert_allclose(pose.q, delta.inverse_kinematics(p), rtol=0, atol=1e-12)
        np.testing.assert_allclose(perfect.jacobian(p), delta.jacobian(p), rtol=0, atol=1e-9)
        np.testing.assert_allclose(perfect.forward_kinematics_floats(pose.q), p, rtol=0, atol=1e-12)


@pytest.mark.parametrize("p", POINTS, ids=["home", "corner", "low"])
def test_unequal_bars_close_with_a_parasitic_rotation(p):
    machine = imperfect()
    pose = machine.inverse_kinematics_full(p)
    expected = machine.bars[:, 9]                                        # L_i + delta, per bar
    np.testing.assert_allclose(bar_lengths(machine, p, pose.rotation, pose.q), expected, rtol=0, atol=1e-12)
    assert 1000 < tilt_urad(log_so3(pose.rotation)) < 2500               # mrad-sized, from 50 um bars
    # an independent solve of the six closures over (w, q), from another start
    def closures(z):
        return bar_lengths(machine, p, exp_so3(z[:3]), z[3:]) - expected
    z = fsolve(closures, np.concatenate((np.full(3, 1e-3), pose.q + 1e-3)), xtol=1e-12)
    np.testing.assert_allclose(exp_so3(z[:3]), pose.rotation, rtol=0, atol=1e-11)
    np.testing.assert_allclose(z[3:], pose.q, rtol=0, atol=1e-11)
    # the forward kinematics of those drives gives the position and the rotation back
    position, rotation = machine.forward_kinematics_full(pose.q)
    np.testing.assert_allclose(position, p, rtol=0, atol=1e-11)
    np.testing.assert_allclose(rotation, pose.rotation, rtol=0, atol=1e-11)


def test_the_tilt_grows_with_the_bar_error():
    delta = load_machine("mom3").model
    errors = np.array([[5e-5, -5e-5], [0.0, 3e-5], [-2e-5, 0.0]])
    tilts = [tilt_urad(ParallelogramMachine("d", delta.legs, 0.03, k * errors, delta.home, delta.workspace)
                       .parasitic_rotation(POINTS[1])) for k in (1.0, 2.0)]
    assert tilts[1] / tilts[0] == pytest.approx(2.0, rel=1e-3)              # first order in the error


def test_jacobian_against_finite_differences():
    machine, h = imperfect(), 1e-6
    for p in POINTS:
        jac = machine.jacobian(p)
        for axis in range(3):
            step = np.zeros(3)
            step[axis] = h
            fd = (machine.inverse_kinematics(p + step, False) - machine.inverse_kinematics(p - step, False)) / (2 * h)
            np.testing.assert_allclose(jac[:, axis], fd, rtol=0, atol=1e-8)


def test_the_gough_measures_the_tilt_the_encoders_cannot():
    """MoM3 §3-4: the three encoders fix the drives, and a perfect-Delta reading of
    them (what an encoder controller computes) gives a translated platform; the six
    Gough struts give the pose, parasitic rotation included."""
    cfg = load_machine("mom3_imperfect")
    machine, met, perfect = cfg.model, cfg.metrology, load_machine("mom3").model
    p = POINTS[1]
    pose = machine.inverse_kinematics_full(p)
    # the Gough plate: mounted 0.1 m below the tool point, turning with the platform
    plate_p = p + pose.rotation @ met.plate_position_in_tool
    plate_r = pose.rotation @ met.plate_rotation_in_tool
    lengths = met.platform.strut_lengths(plate_p, plate_r)
    seen = met.platform.direct_kinematics(lengths, met.platform.home_position, np.eye(3))
    assert seen.converged
    np.testing.assert_allclose(seen.rotation, plate_r, rtol=0, atol=1e-10)
    np.testing.assert_allclose(log_so3(seen.rotation @ met.plate_rotation_in_tool.T), log_so3(pose.rotation),
                               rtol=0, atol=1e-10)
    # the encoders through the perfect model: no rotation, and the position off
    encoder_p = np.asarray(perfect.forward_kinematics_floats(pose.q))
    assert 1e-6 < np.linalg.norm(encoder_p - p) < 1e-3


def test_bad_parallelograms_are_named():
    data = yaml.safe_load((config_dir() / "machines" / "mom3_imperfect.yaml").read_text())
    big = {**data, "parallelogram": {**data["parallelogram"], "bar_length_errors": [[0.1, 0], [0, 0], [0, 0]]}}
    with pytest.raises(ConfigError, match=r"parallelogram.bar_length_errors\[0\]: must be below a tenth"):
        load_machine_data(big)
    two = {**data, "parallelogram": {**data["parallelogram"], "bar_length_errors": [[0, 0]] * 2}}
    with pytest.raises(ConfigError, match=r"bar_length_errors: expected 3 pairs"):
        load_machine_data(two)
    flat = {**data, "parallelogram": {"half_width": 0.0}}
    with pytest.raises(ConfigError, match=r"parallelogram.half_width: must be in \(0"):
        load_machine_data(flat)


def test_pkm_analyze_reports_the_parasitic_rotation(capsys):
    import json

    from pkm_kinematics.cli import main
    assert main(["--json", "report", "--machine", "mom3_imperfect", "--points", "3"]) == 0
    low, high = json.loads(capsys.readouterr().out)["parasitic_rotation_urad"]
    tilts = [tilt_urad(imperfect().parasitic_rotation(p)) for p in imperfect().workspace_grid(3)]
    assert (low, high) == (min(tilts), max(tilts)) and 1000 < low < high < 2500
