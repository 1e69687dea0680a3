"""Planar PRR machines (ARCHI, Sliding Star): IK/FK, Jacobians, ARCHI Figure 10."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_kinematics import JointLimitError, SingularityError, UnreachablePoseError, load_machine
from pkm_kinematics.analysis import condition_map, condition_sweep

ARCHI = load_machine("archi").model
STAR = load_machine("sliding_star").model
L, D = 1.0, 0.2   # ARCHI Figure 10 geometry


def archi_jm_paper(x, y, theta):
    """J_m exactly as printed in ARCHI §3.2 (independent of the general model)."""
    y12, y34 = y - D * math.sin(theta), y + D * math.sin(theta)
    s1, s2 = math.sqrt(L**2 - y12**2), math.sqrt(L**2 - y34**2)
    c, s = math.cos(theta), math.sin(theta)
    return np.array([
        [1, y12 / s1, D * (s - y12 / s1 * c)],
        [1, -y12 / s1, D * (s + y12 / s1 * c)],
        [1, y34 / s2, D * (-s + y34 / s2 * c)],
        [1, -y34 / s2, D * (-s - y34 / s2 * c)],
    ])


def archi_ik_paper(x, y, theta):
    x12, x34 = x - D * math.cos(theta), x + D * math.cos(theta)
    y12, y34 = y - D * math.sin(theta), y + D * math.sin(theta)
    s1, s2 = math.sqrt(L**2 - y12**2), math.sqrt(L**2 - y34**2)
    return np.array([x12 - s1, x12 + s1, x34 - s2, x34 + s2])


archi_poses = st.tuples(st.floats(0.6, 1.4), st.floats(-0.6, -0.25), st.floats(-4 * math.pi, 4 * math.pi))
star_poses = st.tuples(st.floats(-0.3, 0.3), st.floats(-0.15, 0.15), st.floats(-0.35, 0.35))


@settings(max_examples=60, deadline=None)
@given(archi_poses)
def test_archi_ik_matches_paper_and_round_trips(pose):
    pose = np.array(pose)
    q = ARCHI.inverse_kinematics(pose, check_limits=False)
    np.testing.assert_allclose(q, archi_ik_paper(*pose), atol=1e-12)
    # unlimited rotation: FK returns the angle on the revolution of the guess
    res = ARCHI.forward_kinematics(q, guess=pose + [0.0, 0.0, 0.3])
    assert res.converged and res.iterations <= 2
    np.testing.assert_allclose(res.pose, pose, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(star_poses)
def test_sliding_star_round_trip_from_home(pose):
    pose = np.array(pose)
    q = STAR.inverse_kinematics(pose)
    res = STAR.forward_kinematics(q)           # Newton from the home pose, no closed form
    assert res.converged, res.reason
    np.testing.assert_allclose(res.pose, pose, atol=1e-9)
    assert res.residual_m < 1e-9


def test_archi_forward_formula_typo():
    """The seed pairs q1 with q3; only q1-q2 / q3-q4 pairing round-trips."""
    pose = np.array([1.0, -0.4, 0.6])
    q1, q2, q3, q4 = ARCHI.inverse_kinematics(pose)
    consistent = ((q1 + q2) / 2, -math.sqrt(L**2 - (q2 - q1) ** 2 / 4),
                  (q3 + q4) / 2, -math.sqrt(L**2 - (q4 - q3) ** 2 / 4))
    x12, y12, x34, y34 = consistent
    fk = np.array([(x12 + x34) / 2, (y12 + y34) / 2, math.atan2(y34 - y12, x34 - x12)])
    np.testing.assert_allclose(fk, pose, atol=1e-12)
    np.testing.assert_allclose(ARCHI.fk.closed_form([q1, q2, q3, q4]), pose, atol=1e-12)
    typo_x12 = (q1 + q3) / 2
    assert abs(typo_x12 - (pose[0] - D * math.cos(pose[2]))) > 1e-2


@settings(max_examples=40, deadline=None)
@given(archi_poses)
def test_archi_jacobian_matches_paper(pose):
    np.testing.assert_allclose(ARCHI.jacobian(np.array(pose)), archi_jm_paper(*pose), atol=1e-12)


@pytest.mark.parametrize("machine,pose", [(ARCHI, [1.1, -0.35, 2.4]), (STAR, [0.1, -0.05, 0.2])])
def test_jacobian_and_derivative_against_finite_differences(machine, pose):
    pose = np.array(pose)
    h = 1e-6
    fd = np.stack([(machine.inverse_kinematics(pose + h * e, False) - machine.inverse_kinematics(pose - h * e, False))
                   / (2 * h) for e in np.eye(3)], axis=1)
    np.testing.assert_allclose(machine.jacobian(pose), fd, atol=1e-8)
    twist = np.array([0.3, -0.2, 1.1])
    jd_fd = (machine.jacobian(pose + h * twist) - machine.jacobian(pose - h * twist)) / (2 * h)
    np.testing.assert_allclose(machine.jacobian_derivative(pose, twist), jd_fd, atol=1e-7)
    # qddot = J xddot + Jdot xdot (ARCHI §3.4) against a second difference of IK along a path
    acc = np.array([-0.5, 0.4, 2.0])
    q_at = [machine.inverse_kinematics(pose + twist * t + 0.5 * acc * t * t, False) for t in (-h * 10, 0, h * 10)]
    qdd_fd = (q_at[0] - 2 * q_at[1] + q_at[2]) / (h * 10) ** 2
    qdd = machine.jacobian(pose) @ acc + machine.jacobian_derivative(pose, twist) @ twist
    np.testing.assert_allclose(qdd, qdd_fd, atol=1e-4)


def test_batch_versions_agree():
    rng = np.random.default_rng(3)
    poses = np.column_stack([rng.uniform(0.6, 1.4, 200), rng.uniform(-0.6, -0.25, 200), rng.uniform(-7, 7, 200)])
    q, ok = ARCHI.inverse_kinematics_batch(poses)
    assert ok.all()
    for k in range(0, 200, 37):
        np.testing.assert_allclose(q[k], ARCHI.inverse_kinematics(poses[k], False), atol=1e-14)
        np.testing.assert_allclose(ARCHI.jacobian_batch(poses[k:k + 1])[0], ARCHI.jacobian(poses[k]), atol=1e-12)
    fk, conv = ARCHI.forward_kinematics_batch(q, guesses=poses)
    assert conv.all()
    np.testing.assert_allclose(fk, poses, atol=1e-9)
    star = np.column_stack([rng.uniform(-0.3, 0.3, 100), rng.uniform(-0.15, 0.15, 100), rng.uniform(-0.3, 0.3, 100)])
    qs, ok = STAR.inverse_kinematics_batch(star)
    fk, conv = STAR.forward_kinematics_batch(qs)
    assert ok.all() and conv.all()
    np.testing.assert_allclose(fk, star, atol=1e-9)


def test_bad_input_is_refused_with_named_field():
    with pytest.raises(UnreachablePoseError, match="leg q1"):
        ARCHI.inverse_kinematics([1.0, -1.3, 0.0])
    with pytest.raises(ValueError, match="pose"):
        ARCHI.inverse_kinematics([1.0, float("nan"), 0.0])
    with pytest.raises(ValueError, match="pose: expected shape 3"):
        ARCHI.inverse_kinematics([1.0, -0.4])
    with pytest.raises(JointLimitError, match=r"leg q2: position 3.6165.* m outside joint_limits \[-1.5, 3.5\]"):
        ARCHI.inverse_kinematics([2.9, -0.4, 0.0])
    with pytest.raises(ValueError, match="q: contains NaN"):
        ARCHI.forward_kinematics([0.0, np.nan, 0.0, 0.0])


def test_forward_kinematics_reports_impossible_drive_positions():
    res = ARCHI.forward_kinematics([0.0, 2.5, 0.5, 1.0])   # carriages 2.5 m apart, links 1 m
    assert not res.converged and np.isnan(res.pose).all()
    assert "q1, q2" in res.reason


@pytest.mark.parametrize("machine", [ARCHI, STAR], ids=["archi", "sliding_star"])
def test_the_per_cycle_forward_kinematics_is_forward_kinematics(machine):
    """forward_kinematics_floats (the controller's path): the same pose as the checked
    method, warm-started on the revolution of the guess; a failed solve raises its reason."""
    pose = machine.home + [0.01, -0.02, 0.1]
    q = machine.inverse_kinematics(pose).tolist()
    guess = (pose + [0.0, 0.0, 2.0 * math.pi]).tolist()
    np.testing.assert_array_equal(machine.forward_kinematics_floats(q, guess),
                                  machine.forward_kinematics(q, guess).pose)
    np.testing.assert_allclose(machine.forward_kinematics_floats(q, guess), guess, atol=1e-9)
    if machine is ARCHI:
        with pytest.raises(UnreachablePoseError, match="legs q1, q2: carriages 2.5 m apart"):
            machine.forward_kinematics_floats([0.0, 2.5, 0.5, 1.0])


def test_forward_kinematics_least_squares_with_model_error():
    """Drive positions of a machine whose leg 3 is 2 % longer: the nominal model finds
    the least-squares pose and reports the residual instead of hiding it."""
    true = load_machine("archi").model
    legs = list(true.legs)
    legs[2] = type(legs[2])(**{**legs[2].__dict__, "link_length": 1.02})
    real = true.with_legs("archi_real", legs)
    pose = np.array([1.0, -0.4, 0.9])
    res = ARCHI.forward_kinematics(real.inverse_kinematics(pose, False), guess=pose)
    assert res.converged
    assert 1e-4 < res.residual_m < 0.02
    assert np.abs(res.pose - pose).max() < 0.05


def test_archi_figure_10():
    """ARCHI §3.3 Figure 10 (x = 1 m, y = -0.4 m, theta in [-200, 200] deg): every 3-leg
    sub-machine meets a singularity, the 4-leg machine stays well conditioned."""
    sweep = condition_sweep(ARCHI, 1.0, -0.4, -200.0, 200.0)
    assert np.nanmin(sweep.full_condition) == pytest.approx(5.0, abs=1e-6)
    assert np.nanmax(sweep.full_condition) == pytest.approx(11.4564, abs=1e-3)
    expected = {(0, 1, 2): [-199.4712, -30.0, 160.5288], (0, 1, 3): [-150.0, 19.4712],
                (0, 2, 3): [-19.4712, 150.0], (1, 2, 3): [-160.5288, 30.0, 199.4712]}
    assert set(sweep.singular_angles_deg) == set(expected)
    for legs, angles in expected.items():
        np.testing.assert_allclose(sweep.singular_angles_deg[legs], angles, atol=1e-4)
        assert np.nanmax(sweep.sub_condition[legs]) > 1e4
    # independent geometric check: at each singular angle the leg that is alone on its
    # side of the nacelle is aligned with the nacelle (it cannot produce torque about z)
    for legs, angles in sweep.singular_angles_deg.items():
        lone = [leg for leg in legs if sum(1 for k in legs if (k < 2) == (leg < 2)) == 1][0]
        for a in angles:
            pose = np.array([1.0, -0.4, math.radians(a)])
            q = ARCHI.inverse_kinematics(pose, False)
            point = pose[:2] + (D if lone >= 2 else -D) * np.array([math.cos(pose[2]), math.sin(pose[2])])
            e = point - np.array([q[lone], 0.0])
            n = np.array([math.cos(pose[2]), math.sin(pose[2])])
            assert abs(e[0] * n[1] - e[1] * n[0]) / np.linalg.norm(e) < 1e-9
    # the closed form of the condition numbers at theta = 0: J_m columns are orthogonal
    # there, so cond = ratio of column norms
    jm = archi_jm_paper(1.0, -0.4, 0.0)
    norms = np.linalg.norm(jm, axis=0)
    assert ARCHI.condition_number([1.0, -0.4, 0.0]) == pytest.approx(norms.max() / norms.min(), rel=1e-12)


def test_sub_machine_condition_numbers_keys():
    conds = ARCHI.sub_machine_condition_numbers([1.0, -0.4, 0.3])
    assert [ARCHI.sub_machine_name(k) for k in conds] == ["J_123", "J_124", "J_134", "J_234"]


def test_a_platform_point_beyond_its_rail_is_no_other_working_mode():
    """Sliding Star at y = -0.4: the lower platform points pass below the lower rail,
    a regular reachable pose; FK must find it (single and batch)."""
    pose = np.array([0.0, -0.4, 0.0])
    q = STAR.inverse_kinematics(pose, check_limits=False)
    res = STAR.forward_kinematics(q, guess=pose + 0.01)
    assert res.converged, res.reason
    np.testing.assert_allclose(res.pose, pose, atol=1e-9)
    batch, ok = STAR.forward_kinematics_batch(q[None], guesses=(pose + 0.01)[None])
    assert ok[0]
    np.testing.assert_allclose(batch[0], pose, atol=1e-9)


@pytest.mark.parametrize("machine,pose,leg,error", [
    (ARCHI, [1.0, -0.4, 0.9], 3, 0.01),
    (STAR, [0.05, 0.02, 0.1], 2, 0.1),
])
def test_least_squares_forward_kinematics_with_a_drive_offset(machine, pose, leg, error):
    """A drive reading off by 1 cm / 10 cm: single and batch agree on the least-squares
    pose; the reported residual is the leg misfit at the returned pose."""
    q = machine.inverse_kinematics(pose, check_limits=False)
    q[leg] += error
    res = machine.forward_kinematics(q, guess=pose)
    assert res.converged, res.reason
    batch, ok = machine.forward_kinematics_batch(q[None], guesses=np.array([pose]))
    assert ok[0]
    np.testing.assert_allclose(batch[0], res.pose, atol=1e-9)
    # residual recomputed independently at the returned pose
    c, s = math.cos(res.pose[2]), math.sin(res.pose[2])
    misfit = []
    for lg, qi in zip(machine.legs, q):
        b = np.array([c * lg.platform_point[0] - s * lg.platform_point[1],
                      s * lg.platform_point[0] + c * lg.platform_point[1]])
        carriage = np.array(lg.rail_origin) + qi * np.array(lg.rail_direction) / np.linalg.norm(lg.rail_direction)
        misfit.append(abs(np.linalg.norm(res.pose[:2] + b - carriage) - lg.link_length))
    assert res.residual_m == pytest.approx(max(misfit), rel=1e-9)
    # a least-squares optimum: the gradient of sum f_i^2 vanishes
    h = 1e-6
    def cost(x):
        out = 0.0
        cc, ss = math.cos(x[2]), math.sin(x[2])
        for lg, qi in zip(machine.legs, q):
            b = np.array([cc * lg.platform_point[0] - ss * lg.platform_point[1],
                          ss * lg.platform_point[0] + cc * lg.platform_point[1]])
            carriage = np.array(lg.rail_origin) + qi * np.array(lg.rail_direction) / np.linalg.norm(lg.rail_direction)
            out += (np.linalg.norm(x[:2] + b - carriage) - lg.link_length) ** 2
        return out
    grad = [(cost(res.pose + h * e) - cost(res.pose - h * e)) / (2 * h) for e in np.eye(3)]
    assert np.abs(grad).max() < 1e-8


def test_singular_and_malformed_inputs_raise_clear_errors():
    # leg q1 perpendicular to its rail: y12 = -L
    with pytest.raises(SingularityError, match="leg q1 is perpendicular to its rail"):
        ARCHI.jacobian([1.0, -1.0, 0.0])
    cond = condition_map(ARCHI, np.array([[1.0, -1.0, 0.0]]))
    assert np.isinf(cond[0])
    pose = [1.0, -0.4, 0.3]
    q = ARCHI.inverse_kinematics(pose)
    np.testing.assert_allclose(ARCHI.jacobian(pose, q=list(q)), ARCHI.jacobian(pose))
    with pytest.raises(ValueError, match="twist: expected shape 3"):
        ARCHI.jacobian_derivative(pose, [1.0, 2.0])
    with pytest.raises(ValueError, match="twist: contains NaN"):
        ARCHI.jacobian_derivative(pose, [1.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="guesses: expected shape"):
        STAR.forward_kinematics_batch(np.zeros((2, 4)), guesses=np.zeros(3))
    with pytest.raises(UnreachablePoseError):
        ARCHI.inverse_kinematics([1e200, -0.4, 0.0])
    # huge but finite values are not "NaN"
    with pytest.raises(UnreachablePoseError):
        ARCHI.inverse_kinematics([1e308, 1e308, 0.0])


def test_check_joint_limits():
    ARCHI.check_joint_limits(ARCHI.inverse_kinematics([1.0, -0.4, 0.3]))
    with pytest.raises(JointLimitError, match="leg q3"):
        ARCHI.check_joint_limits(np.array([0.0, 1.0, -2.0, 2.0]))
