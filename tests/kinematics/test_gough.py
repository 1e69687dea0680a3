"""Gough metrology platform: inverse model, Jacobians (MoM3 eq. 2-3, 10-11), the DKM,
and the worst-case resolution analysis of MoM3 §5."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pkm_kinematics import GoughDKMSolver, load_machine
from pkm_kinematics.analysis import gough_resolution, optimize_gough_geometry, resolution_at
from pkm_kinematics.rotations import exp_so3, rotation_from_rpy, rpy_from_rotation

MET = load_machine("mom3").metrology
GOUGH = MET.platform
HOME = GOUGH.home_position


def test_strut_lengths_direct():
    rot = rotation_from_rpy(0.02, -0.01, 0.3)
    p = HOME + [0.05, -0.02, 0.1]
    expected = [np.linalg.norm(p + rot @ b - a) for a, b in zip(GOUGH.base_points, GOUGH.plate_points)]
    np.testing.assert_allclose(GOUGH.strut_lengths(p, rot), expected, atol=1e-15)
    # MoM3 Table 1 geometry on the circles
    np.testing.assert_allclose(np.linalg.norm(GOUGH.base_points, axis=1), 0.375)
    np.testing.assert_allclose(np.linalg.norm(GOUGH.plate_points, axis=1), 0.075)


def test_inverse_jacobian_against_finite_differences():
    """ldot = J_h^-1 [v; omega], omega in the base frame (R(t) = exp([omega t]x) R)."""
    rot = rotation_from_rpy(0.1, -0.05, 0.4)
    p = HOME + [0.03, 0.1, -0.05]
    h = 1e-7
    fd = np.zeros((6, 6))
    for k in range(3):
        e = np.eye(3)[k]
        fd[:, k] = (GOUGH.strut_lengths(p + h * e, rot) - GOUGH.strut_lengths(p - h * e, rot)) / (2 * h)
        fd[:, 3 + k] = (GOUGH.strut_lengths(p, exp_so3(h * e) @ rot)
                        - GOUGH.strut_lengths(p, exp_so3(-h * e) @ rot)) / (2 * h)
    np.testing.assert_allclose(GOUGH.inverse_jacobian(p, rot), fd, atol=1e-7)


def test_tool_jacobian_against_finite_differences():
    """dp_t = J_t dl (MoM3 eq. 10-11): perturb each strut, solve the DKM, move the tool."""
    rot = rotation_from_rpy(0.01, 0.02, -0.03)
    p = HOME + [0.05, -0.05, 0.05]
    tool = np.array([0.01, -0.01, -0.2])
    lengths = GOUGH.strut_lengths(p, rot)
    h = 1e-6
    fd = np.zeros((3, 6))
    for k in range(6):
        tips = []
        for sign in (1, -1):
            res = GOUGH.direct_kinematics(lengths + sign * h * np.eye(6)[k], p, rot, tol_m=1e-13)
            assert res.converged
            tips.append(res.position + res.rotation @ tool)
        fd[:, k] = (tips[0] - tips[1]) / (2 * h)
    np.testing.assert_allclose(GOUGH.tool_jacobian(p, rot, tool), fd, atol=1e-6)


poses = st.tuples(*[st.floats(-0.15, 0.15)] * 3, *[st.floats(-0.15, 0.15)] * 3)


@settings(max_examples=60, deadline=None)
@given(poses)
def test_dkm_round_trip_cold_start(x):
    """From the home pose, up to 150 mm and 8.6 deg away: converges, right branch."""
    p, rot = HOME + np.array(x[:3]), rotation_from_rpy(*x[3:])
    res = GOUGH.direct_kinematics(GOUGH.strut_lengths(p, rot))
    assert res.converged, res.reason
    assert res.iterations <= 8
    # strut tolerance 1e-10 m on each of six struts: pose error below sqrt(6) ||J_h|| x 1e-10
    # (~6 um/um, ~60 urad/um)
    np.testing.assert_allclose(res.position, p, atol=5e-9)
    np.testing.assert_allclose(res.rotation, rot, atol=2e-8)


def test_dkm_warm_start_takes_few_iterations():
    """A 2 kHz stream along a 0.2 m/s path: each solve starts from the last one."""
    solver = GoughDKMSolver(GOUGH)
    iterations, evaluations = [], 0
    for k in range(400):
        t = k / 2000.0
        p = HOME + [0.1 * math.sin(2 * t), 0.05 * math.cos(3 * t), 0.02 * t]
        rot = rotation_from_rpy(1e-4 * math.sin(t), 2e-4 * t, 1e-4)
        res = solver.solve(GOUGH.strut_lengths(p, rot))
        assert res.converged
        # strut tolerance 1e-10 m x ||J_h|| (about 20 here) bounds the pose error
        np.testing.assert_allclose(res.position, p, atol=5e-9)
        iterations.append(res.iterations)
        evaluations += res.jacobian_evaluations
    # constant-velocity extrapolation from the third solve on: one Newton step mostly
    assert max(iterations[2:]) <= 2 and np.median(iterations) == 1
    assert evaluations < 200     # J_h is re-evaluated in fewer than half of the solves


def test_dkm_proper_rotation_update_handles_large_angles():
    """Iteration count must not grow with the angle (genhexkins' RPY-increment update does)."""
    counts = []
    for angle in (0.05, 0.2, 0.4, 0.6):
        rot = rotation_from_rpy(0.0, 0.0, angle)
        lengths = GOUGH.strut_lengths(HOME, rot)
        res = GOUGH.direct_kinematics(lengths, HOME, rotation_from_rpy(0, 0, angle - 0.05))
        assert res.converged
        np.testing.assert_allclose(rpy_from_rotation(res.rotation)[2], angle, atol=1e-10)
        counts.append(res.iterations)
    assert max(counts) - min(counts) <= 1


def test_dkm_reports_impossible_strut_sets_truthfully():
    lengths = GOUGH.strut_lengths(HOME, np.eye(3))
    for bad in (lengths * [1, 1, 1, 1, 1, 2.5], np.full(6, 0.05), lengths + [0.4, -0.4, 0.4, -0.4, 0.4, -0.4]):
        res = GOUGH.direct_kinematics(bad, max_iterations=12)
        assert not res.converged
        assert np.isnan(res.position).all() and np.isnan(res.rotation).all()
        assert res.reason and 1 <= res.iterations <= 12
        assert res.residual_m > 1e-6


def test_dkm_refuses_the_mirror_assembly():
    mirror_guess = HOME * [1, 1, -1]
    res = GOUGH.direct_kinematics(GOUGH.strut_lengths(HOME, np.eye(3)), mirror_guess, np.eye(3))
    assert not res.converged and "mirror" in res.reason


def test_dkm_validates_input():
    with pytest.raises(ValueError, match="strut lengths: contains NaN"):
        GOUGH.direct_kinematics([0.8, 0.8, np.nan, 0.8, 0.8, 0.8])
    with pytest.raises(ValueError, match="must be > 0"):
        GOUGH.direct_kinematics([0.8, 0.8, -0.8, 0.8, 0.8, 0.8])
    with pytest.raises(ValueError, match="expected shape 6"):
        GOUGH.direct_kinematics([0.8] * 5)


def test_dkm_batch_agrees():
    rng = np.random.default_rng(5)
    n = 500
    p = HOME + rng.uniform(-0.15, 0.15, (n, 3))
    rot = np.array([rotation_from_rpy(*r) for r in rng.uniform(-0.05, 0.05, (n, 3))])
    lengths = GOUGH.strut_lengths_batch(p, rot)
    guess_p = p + rng.normal(0, 1e-4, (n, 3))
    guess_r = np.array([exp_so3(w) @ r for w, r in zip(rng.normal(0, 1e-3, (n, 3)), rot)])
    pos, rots, ok, iters = GOUGH.direct_kinematics_batch(lengths, guess_p, guess_r)
    assert ok.all() and iters.max() <= 4
    np.testing.assert_allclose(pos, p, atol=1e-9)
    np.testing.assert_allclose(rots, rot, atol=1e-8)   # 1e-10 m strut tolerance x 60 urad/um
    lengths[7] = 0.05
    pos, rots, ok, _ = GOUGH.direct_kinematics_batch(lengths, guess_p, guess_r)
    assert not ok[7] and np.isnan(pos[7]).all() and ok.sum() == n - 1


def test_mom3_resolution_matches_the_paper():
    """MoM3 §5.6: with 1 um scales about 6 um in position and 12 um at the tool level
    (worst case over the 300 mm cube and the tool box); the struts stay in 634-1080 mm."""
    res = gough_resolution(GOUGH, MET.encoder_resolution_m, MET.tool_box, MET.workspace_center,
                           MET.workspace_size_m, points_per_axis=7)
    assert 5.5e-6 < res.position_m < 6.5e-6
    assert 10e-6 < res.tool_m < 13e-6
    assert res.struts_within_limits
    assert 0.634 <= res.strut_range[0] and res.strut_range[1] <= 1.080


def test_tool_level_worst_case_lies_on_a_box_corner():
    """MoM3 §5.5.2: the maximum of ||dp_t|| over the tool box is on one of its corners -
    a dense sampling of the box interior never beats the corner evaluation."""
    rng = np.random.default_rng(2)
    pos = np.array([[0.1, -0.12, 0.85]])
    _, _, corner_max = resolution_at(GOUGH, pos, 1e-6, MET.tool_box)
    jh = GOUGH.jacobian(pos[0], np.eye(3))
    dl = 1e-6 * np.array(list(itertools.product((-1, 1), repeat=6)))
    dx = dl @ jh.T
    pts = rng.uniform(MET.tool_box[:, 0], MET.tool_box[:, 1], (400, 3))
    dense = max(np.linalg.norm(dx[:, :3] + np.cross(dx[:, 3:], pt), axis=1).max() for pt in pts)
    assert dense <= corner_max[0] * (1 + 1e-12)
    # and the 2^6 vertices bound every interior strut error (linearity, eq. 12)
    inner = rng.uniform(-1e-6, 1e-6, (2000, 6)) @ jh.T
    assert np.linalg.norm(inner[:, :3], axis=1).max() <= np.linalg.norm(dx[:, :3], axis=1).max()


def test_geometry_optimizer_does_not_do_worse_than_table_1():
    design = optimize_gough_geometry(1e-6, MET.tool_box, MET.workspace_center, 0.3, (0.634, 1.080),
                                     points_per_axis=3, maxiter=15, popsize=8, seed=3)
    table1 = gough_resolution(GOUGH, 1e-6, MET.tool_box, MET.workspace_center, 0.3, points_per_axis=3)
    assert design.criterion_m <= table1.tool_m * 1.001
    assert 0.634 - 1e-9 <= design.strut_range[0] and design.strut_range[1] <= 1.080 + 1e-9


def test_dkm_batch_cold_start_relinearises_and_matches_single_solves():
    """From the home pose (up to 150 mm / 6 deg away) the chord Jacobian must be
    re-evaluated per row; every row ends where the scalar solver ends."""
    rng = np.random.default_rng(9)
    n = 64
    p = HOME + rng.uniform(-0.15, 0.15, (n, 3))
    rot = np.array([rotation_from_rpy(*r) for r in rng.uniform(-0.1, 0.1, (n, 3))])
    lengths = GOUGH.strut_lengths_batch(p, rot)
    lengths[5] = GOUGH.strut_lengths(HOME, np.eye(3)) * [1, 1, 1, 1, 1, 2.5]   # impossible
    pos, rots, ok, iters = GOUGH.direct_kinematics_batch(
        lengths, np.tile(HOME, (n, 1)), np.tile(np.eye(3), (n, 1, 1)), chunk=16)
    for k in range(n):
        single = GOUGH.direct_kinematics(lengths[k])
        assert ok[k] == single.converged
        if single.converged:
            np.testing.assert_allclose(pos[k], single.position, atol=1e-9)
            np.testing.assert_allclose(pos[k], p[k], atol=5e-9)
            np.testing.assert_allclose(rots[k], rot[k], atol=1e-8)
    assert not ok[5] and np.isnan(pos[5]).all()
    assert iters[ok].max() > 2          # genuinely iterated from far away


def test_guess_must_be_a_rotation():
    """Six struts cannot see a non-rigid plate: a distorted guess would survive the
    iteration, so it is refused up front."""
    lengths = GOUGH.strut_lengths(HOME + [0.02, 0.01, 0.03], rotation_from_rpy(0.01, 0.02, 0.03))
    shear = np.eye(3)
    shear[0, 1] = 0.2
    for bad in (1.05 * np.eye(3), shear, np.diag([1.0, 1.0, -1.0])):
        with pytest.raises(ValueError, match="guess_rotation: not a rotation matrix"):
            GOUGH.direct_kinematics(lengths, HOME, bad)
    with pytest.raises(ValueError, match="rotation: not a rotation matrix"):
        GoughDKMSolver(GOUGH).reset(rotation=2 * np.eye(3))
    with pytest.raises(ValueError, match="guess_rotations\\[1\\]: not a rotation"):
        GOUGH.direct_kinematics_batch(np.tile(lengths, (2, 1)), np.tile(HOME, (2, 1)),
                                      np.stack([np.eye(3), 1.05 * np.eye(3)]))
    with pytest.raises(ValueError, match="jacobian_guess: expected shape 6x6"):
        GOUGH.direct_kinematics(lengths, jacobian_guess=np.eye(3))


def test_far_guesses_never_return_another_assembly_mode():
    """From random guesses up to 0.6 m and 2 rad away the solver either finds the true
    pose or reports a failure; the other assembly modes above the base (same strut
    lengths, det(J_h^-1) of the other sign) are refused, in both solvers."""
    rng = np.random.default_rng(0)
    p_true, r_true = HOME + [0.05, -0.03, 0.02], rotation_from_rpy(0.05, -0.04, 0.1)
    lengths = GOUGH.strut_lengths(p_true, r_true)
    guesses_p = HOME + rng.uniform(-0.6, 0.6, (400, 3))
    guesses_r = np.array([exp_so3(w) for w in rng.uniform(-2.0, 2.0, (400, 3))])
    reasons = set()
    converged = 0
    for gp, gr in zip(guesses_p, guesses_r):
        res = GOUGH.direct_kinematics(lengths, gp, gr, max_iterations=30)
        if res.converged:
            converged += 1
            np.testing.assert_allclose(res.position, p_true, atol=5e-9)
            np.testing.assert_allclose(res.rotation, r_true, atol=1e-8)
        else:
            reasons.add(res.reason.split(":")[0])
    assert converged > 50 and "another assembly mode" in reasons
    pos, rot, ok, _ = GOUGH.direct_kinematics_batch(np.tile(lengths, (400, 1)), guesses_p, guesses_r,
                                                    max_iterations=30)
    assert ok.sum() > 50
    np.testing.assert_allclose(pos[ok], np.tile(p_true, (ok.sum(), 1)), atol=5e-9)


def test_orientation_resolution_parts():
    """The paper's "about 30 urad" is the tilt; the rotation about z is twice that."""
    res = gough_resolution(GOUGH, 1e-6, MET.tool_box, MET.workspace_center, 0.3, points_per_axis=7)
    assert 25e-6 < res.tilt_rad < 35e-6
    assert res.twist_rad > 1.5 * res.tilt_rad
    assert res.orientation_rad >= max(res.tilt_rad, res.twist_rad)



@settings(max_examples=50, deadline=None)
@given(st.floats(-0.2, 0.2), st.floats(-0.2, 0.2), st.floats(-0.1, 0.1), st.floats(-0.3, 0.3),
       st.floats(-0.3, 0.3), st.floats(-1.0, 1.0))
def test_jacobian_rows_for_the_loop_equal_the_numpy_jacobian(dx, dy, dz, roll, pitch, yaw):
    rot = rotation_from_rpy(roll, pitch, yaw)
    p = HOME + [dx, dy, dz]
    rows = GOUGH.jacobian_rows(p.tolist(), tuple(rot.ravel().tolist()))
    # two LAPACK inverses (numba's, numpy's) of entries up to ~60: last bits differ
    np.testing.assert_allclose(np.array(rows), GOUGH.jacobian(p, rot), rtol=1e-10, atol=1e-10)


def test_the_compiled_stream_is_the_per_reading_solver_bit_for_bit():
    """GoughDKMSolver.solve_stream against N calls of solve on the same stream, a
    reading that cannot be solved in the middle (the state restarts from the last good
    pose, as solve does), and the state after both the same."""
    from pkm_kinematics import GoughDKMSolver, load_machine
    from pkm_kinematics.rotations import rotation_from_rpy
    platform = load_machine("mom3").metrology.platform
    home = platform.home_position
    lengths = np.array([platform.strut_lengths(home + 1e-4 * k * np.array([1.0, -0.5, 0.2]),
                                               rotation_from_rpy(2e-4 * k, -1e-4 * k, 3e-4 * k)) for k in range(60)])
    lengths[30] += [0.3, 0.0, 0.0, 0.0, 0.0, -0.2]              # not a pose of the platform: fails
    one, many = GoughDKMSolver(platform, tol_m=1e-10), GoughDKMSolver(platform, tol_m=1e-10)
    results = [one.solve(q) for q in lengths]
    positions, rotations, converged, iterations = many.solve_stream(lengths)
    assert converged.tolist() == [r.converged for r in results] and not converged[30] and converged.sum() == 59
    np.testing.assert_array_equal(positions, [r.position for r in results])
    np.testing.assert_array_equal(rotations, [r.rotation for r in results])
    assert iterations.tolist() == [r.iterations for r in results]
    np.testing.assert_array_equal(one.solve(lengths[-1]).position, many.solve(lengths[-1]).position)
