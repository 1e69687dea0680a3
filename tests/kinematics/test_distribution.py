"""Force distribution: every method reproduces the wrench and is optimal for its
criterion, checked against scipy's general-purpose optimisers."""

import math

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog, minimize, minimize_scalar

from pkm_kinematics import DistributionError, load_machine
from pkm_kinematics import distribution as fd
from pkm_kinematics.planar import pair_force_map

ARCHI = load_machine("archi").model
STAR = load_machine("sliding_star").model

finite = st.floats(-1.0, 1.0, allow_nan=False)
jacobians = st.lists(finite, min_size=12, max_size=12).map(lambda v: np.array(v).reshape(4, 3))
wrenches = st.lists(st.floats(-500.0, 500.0), min_size=3, max_size=3).map(np.array)


def well_conditioned(jac):
    s = np.linalg.svd(jac, compute_uv=False)
    return s[-1] > 1e-2 * s[0]


@settings(max_examples=150, deadline=None)
@given(jacobians, wrenches)
# a leg of slope ~1e-9 against two nearly parallel ones: the crossing heights tie in floats
@example(np.array([0, 1, -1, 1, 0.25, 0, 1e-8, 0, -0.5, 0, 0, 0.5]).reshape(4, 3), np.array([0.0, 1, -1]))
def test_min_inf_norm_is_exact(jac, wrench):
    assume(well_conditioned(jac))
    f = fd.min_inf_norm(jac, wrench)
    np.testing.assert_allclose(jac.T @ f, wrench, atol=1e-8 * max(1.0, np.abs(wrench).max()))
    # reference: the LP min s s.t. J^T f = F, |f_i| <= s, solved by HiGHS
    n = 4
    res = linprog(np.r_[np.zeros(n), 1.0],
                  A_ub=np.block([[np.eye(n), -np.ones((n, 1))], [-np.eye(n), -np.ones((n, 1))]]),
                  b_ub=np.zeros(2 * n), A_eq=np.hstack([jac.T, np.zeros((3, 1))]), b_eq=wrench,
                  bounds=[(None, None)] * (n + 1), method="highs")
    assert res.success
    # HiGHS's tolerances (it also drops matrix entries under 1e-9, which the draws reach)
    assert np.abs(f).max() == pytest.approx(res.fun, rel=1e-6, abs=1e-7)
    assert np.abs(f).max() <= np.abs(fd.min_two_norm(jac, wrench)).max() * (1 + 1e-9) + 1e-12   # + subnormal wrenches


def test_min_inf_norm_with_a_leg_outside_the_null_space():
    """A leg with no null-space component sets a floor; among the optimal solutions
    the one of least 2-norm is returned (continuity with the pseudo-inverse)."""
    jac = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    n = fd.null_direction(jac)
    assert abs(n[0]) < 1e-15
    wrench = np.array([100.0, 1.0, 2.0])
    f = fd.min_inf_norm(jac, wrench)
    assert np.abs(f).max() == pytest.approx(100.0)
    np.testing.assert_allclose(f, fd.min_two_norm(jac, wrench), atol=1e-12)


def test_min_inf_norm_with_a_single_leg_in_the_null_space():
    """A drive that cannot act on the platform (zero row) carries the whole null space:
    the optimum leaves it unloaded."""
    jac = np.array([[1.0, 0.2, 0.0], [0.0, 1.0, 0.3], [0.1, 0.0, 1.0], [0.0, 0.0, 0.0]])
    wrench = np.array([5.0, -7.0, 2.0])
    f = fd.min_inf_norm(jac, wrench)
    np.testing.assert_allclose(f, np.r_[np.linalg.solve(jac[:3].T, wrench), 0.0], atol=1e-12)


def _p_norm(x, p: float) -> float:
    top = np.abs(x).max()
    return float(top * np.sum((np.abs(x) / top) ** p) ** (1.0 / p)) if top > 0.0 else 0.0


@settings(max_examples=80, deadline=None)
@given(jacobians, wrenches, st.sampled_from([3.0, 4.0, 8.0, 32.0, 64.0]))
@example(np.array([1e-13, 0, 0, 0, 1, 0, 0.125, 0, 0, 0, 0, 1]).reshape(4, 3), np.array([244.0, 0, 0]), 64.0)
def test_min_p_norm_against_scipy(jac, wrench, p):
    assume(well_conditioned(jac) and np.abs(wrench).max() > 1.0)
    f = fd.min_p_norm(jac, wrench, p)
    np.testing.assert_allclose(jac.T @ f, wrench, atol=1e-8 * np.abs(wrench).max())
    f0, n = fd.min_two_norm(jac, wrench), fd.null_direction(jac)
    # the p-norm as max * ||x / max||_p: the p-th power of forces in the hundreds
    # overflowed a float at p = 64 wherever the line search went (same minimiser)
    ref = minimize_scalar(lambda t: _p_norm(f0 + t * n, p), bracket=(-1.0, 1.0), tol=1e-12)
    assert _p_norm(f, p) <= ref.fun * (1 + 1e-9) + 1e-12
    # each optimum is optimal for its own norm only (relative tolerances: where the null
    # space does not help, the optima coincide up to rounding of forces in the thousands)
    assert np.linalg.norm(f) >= np.linalg.norm(f0) * (1 - 1e-9)
    assert np.abs(f).max() >= np.abs(fd.min_inf_norm(jac, wrench)).max() * (1 - 1e-9)


def test_two_dimensional_null_space_uses_lp_and_bfgs():
    rng = np.random.default_rng(1)
    jac = rng.normal(size=(5, 3))
    wrench = np.array([10.0, -20.0, 5.0])
    f_inf = fd.min_inf_norm(jac, wrench)
    np.testing.assert_allclose(jac.T @ f_inf, wrench, atol=1e-8)
    basis = fd.null_space(jac)
    assert basis.shape == (5, 2)
    f0 = fd.min_two_norm(jac, wrench)
    ref = minimize(lambda z: np.abs(f0 + basis @ z).max(), np.zeros(2), method="Nelder-Mead",
                   options={"xatol": 1e-12, "fatol": 1e-12, "maxiter": 20000})
    assert np.abs(f_inf).max() <= ref.fun + 1e-7
    f4 = fd.min_p_norm(jac, wrench, 4.0)
    np.testing.assert_allclose(jac.T @ f4, wrench, atol=1e-8)
    ref4 = minimize(lambda z: np.sum((f0 + basis @ z) ** 4), np.zeros(2), method="Nelder-Mead",
                    options={"xatol": 1e-12, "fatol": 1e-14, "maxiter": 20000})
    assert np.sum(f4**4) <= ref4.fun * (1 + 1e-6)


def test_pseudo_inverse_and_projection():
    pose = np.array([1.0, -0.4, 0.7])
    jac = ARCHI.jacobian(pose)
    wrench = np.array([50.0, -200.0, 12.0])
    f = fd.min_two_norm(jac, wrench)
    np.testing.assert_allclose(f, np.linalg.pinv(jac.T) @ wrench, atol=1e-10)
    n = fd.null_direction(jac)
    assert abs(f @ n) < 1e-10                       # no internal force
    np.testing.assert_allclose(jac.T @ n, 0.0, atol=1e-12)
    # Sliding Star eq. 8: same platform force, internal part removed, idempotent
    nd = np.array([120.0, -40.0, 300.0, 10.0])
    proj = fd.project_forces(jac, nd)
    np.testing.assert_allclose(jac.T @ proj, jac.T @ nd, atol=1e-9)
    np.testing.assert_allclose(fd.project_forces(jac, proj), proj, atol=1e-9)
    np.testing.assert_allclose(fd.internal_force(jac, nd), (nd @ n) * n, atol=1e-9)
    assert np.linalg.norm(proj) <= np.linalg.norm(nd)


def test_prestress_leaves_the_wrench_and_sets_the_internal_force():
    jac = STAR.jacobian([0.1, 0.0, 0.1])
    wrench = np.array([30.0, 40.0, 5.0])
    base = fd.min_two_norm(jac, wrench)
    ref = np.ones(4)
    f = fd.add_prestress(jac, base, 250.0, reference=ref)
    np.testing.assert_allclose(jac.T @ f, wrench, atol=1e-9)
    assert np.linalg.norm(fd.internal_force(jac, f)) == pytest.approx(250.0)
    assert fd.null_direction(jac, reference=ref) @ ref >= 0
    assert fd.null_direction(jac, reference=-ref) @ ref <= 0


@pytest.mark.parametrize("theta", [0.3, math.pi / 4, 1.2, 2.9])
def test_two_arm_matches_archi_section_4_3(theta):
    pose = np.array([1.0, -0.4, theta])
    wrench = np.array([40.0, -150.0, 8.0])
    f = fd.two_arm(ARCHI, pose, wrench)
    np.testing.assert_allclose(ARCHI.jacobian(pose).T @ f, wrench, atol=1e-9)
    # J_f printed in ARCHI §4.3.1 with d = 0.2
    d, c, s = 0.2, math.cos(theta), math.sin(theta)
    jf_paper = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [d * s, -d * c, -d * s, d * c], [c, s, -c, -s]])
    force_map, jf = pair_force_map(ARCHI, pose)
    np.testing.assert_allclose(jf, jf_paper, atol=1e-12)
    # independent statics: a link is a two-force member, so drive k pushes its platform
    # point with f_k e_k / (e_k . u_k) (rail u_k = x here); sum per shared point
    def point_forces(forces):
        q = ARCHI.inverse_kinematics(pose, check_limits=False)
        b12 = pose[:2] - d * np.array([c, s])
        b34 = pose[:2] + d * np.array([c, s])
        out = np.zeros(4)
        for k, point in enumerate((b12, b12, b34, b34)):
            e = point - np.array([q[k], 0.0])
            out[2 * (k // 2):2 * (k // 2) + 2] += forces[k] * e / e[0]
        return out
    pts = point_forces(f)
    np.testing.assert_allclose(pts[:2] + pts[2:], wrench[:2], atol=1e-9)
    assert (pts[:2] - pts[2:]) @ [c, s] == pytest.approx(0.0, abs=1e-9)
    # with gravity (§4.3.2): (f1 - f2) . n = M_n G sin(theta)
    k = fd.two_arm_gravity_internal_force(20.0, theta)
    fg = fd.two_arm(ARCHI, pose, wrench, k)
    ptsg = point_forces(fg)
    assert (ptsg[:2] - ptsg[2:]) @ [c, s] == pytest.approx(20.0 * 9.81 * s, rel=1e-9)
    # the gravity vector form: -M_n g . n, the same for g = (0, -G); a machine lying on
    # its side (g along +x) gets -M_n G cos(theta)
    assert fd.two_arm_gravity_internal_force(20.0, theta, (0.0, -9.81)) == pytest.approx(k, rel=1e-12)
    assert fd.two_arm_gravity_internal_force(20.0, theta, (9.81, 0.0)) == pytest.approx(-20.0 * 9.81 * c, rel=1e-12)
    np.testing.assert_allclose(ARCHI.jacobian(pose).T @ fg, wrench, atol=1e-9)


def test_inf_norm_beats_pseudo_inverse_along_the_archi_rotation():
    """ARCHI §4.5 / Fig. 17-18: over the nacelle turning from pi/4 to pi/2 under a
    constant wrench, the exact infinity-norm solution never has a higher peak."""
    wrench = np.array([100.0, -300.0, 20.0])
    peaks_inf, peaks_2 = [], []
    for theta in np.linspace(math.pi / 4, math.pi / 2, 50):
        jac = ARCHI.jacobian([1.0, -0.4, theta])
        peaks_inf.append(np.abs(fd.min_inf_norm(jac, wrench)).max())
        peaks_2.append(np.abs(fd.min_two_norm(jac, wrench)).max())
    assert all(a <= b + 1e-9 for a, b in zip(peaks_inf, peaks_2))
    assert max(peaks_inf) < 0.95 * max(peaks_2)
    # exact solution is continuous: no jump like the gradient method of Fig. 18
    assert np.abs(np.diff(peaks_inf)).max() < 0.05 * max(peaks_inf)


def test_errors():
    singular = np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 3.0, 0.0]])
    with pytest.raises(DistributionError, match="singular"):
        fd.min_two_norm(singular, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="distribution: must be one of"):
        fd.distribute("magic", ARCHI.jacobian([1.0, -0.4, 0.5]), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="two-arm model"):
        pair_force_map(STAR, [0.0, 0.0, 0.0])
    with pytest.raises(DistributionError, match="does not reproduce"):
        fd.check_wrench(np.eye(3), np.array([1.0, 2.0, 3.0]), [1.0, 2.0, 4.0])


def test_distribute_dispatch():
    pose = np.array([1.0, -0.4, 0.5])
    jac = ARCHI.jacobian(pose)
    wrench = np.array([10.0, 20.0, 3.0])
    n = fd.null_direction(jac)
    direct = {"pseudo_inverse": fd.min_two_norm(jac, wrench), "inf_norm": fd.min_inf_norm(jac, wrench),
              "p_norm": fd.min_p_norm(jac, wrench, 4.0), "two_arm": fd.two_arm(ARCHI, pose, wrench),
              "two_arm_gravity": fd.two_arm(ARCHI, pose, wrench, 30.0)}
    assert set(direct) == set(fd.METHODS)
    for method, expected in direct.items():
        internal = 30.0 if method == "two_arm_gravity" else 0.0     # the caller's M_n G sin(theta)
        np.testing.assert_allclose(fd.distribute(method, jac, wrench, machine=ARCHI, pose=pose,
                                                 internal_force_n=internal), expected)
        f = fd.distribute(method, jac, wrench, machine=ARCHI, pose=pose, prestress_n=5.0, internal_force_n=internal)
        np.testing.assert_allclose(f - expected, 5.0 * n, atol=1e-9)


def test_malformed_input():
    jac = ARCHI.jacobian([1.0, -0.4, 0.5])
    with pytest.raises(ValueError, match="wrench: expected shape 3"):
        fd.min_two_norm(jac, [1.0, 2.0])
    with pytest.raises(ValueError, match="wrench: contains NaN"):
        fd.min_inf_norm(jac, [1.0, np.nan, 2.0])
    with pytest.raises(ValueError, match="jac: expected an n x m Jacobian"):
        fd.min_two_norm([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match=r"p: must be in \[2, 64\]"):
        fd.min_p_norm(jac, [1.0, 2.0, 3.0], 100.0)
