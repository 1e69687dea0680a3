"""The rail kernels of the bar model on a machine none of the seed machines is: six
rails in space driving a platform that translates and turns (all six twist columns),
against finite differences of the closed-form IK along the motion."""

import numpy as np

from pkm_kinematics import bars as B
from pkm_kinematics.rotations import exp_so3


def six_rail_machine(seed=3):
    rng = np.random.default_rng(seed)
    base = rng.normal(0.0, 0.5, (6, 3))
    rail = rng.normal(0.0, 1.0, (6, 3))
    rail /= np.linalg.norm(rail, axis=1, keepdims=True)
    platform = rng.normal(0.0, 0.15, (6, 3))
    return B.bar_rows(base, platform, actuator=np.arange(6), kind=B.RAIL, rail=rail, length=np.full(6, 2.0),
                      branch=rng.choice([-1.0, 1.0], 6))


def ik(bars, p, rot):
    q = np.empty(6)
    assert B.inverse_kinematics_into(bars, np.asarray(p, float), np.ascontiguousarray(rot).reshape(9).copy(), q) \
        == (B.IK_OK, -1)
    return q


def test_the_rail_velocity_terms_match_finite_differences_of_the_ik_on_a_turning_platform():
    bars = six_rail_machine()
    p0, r0 = np.array([0.05, -0.02, 0.1]), exp_so3(np.array([0.1, -0.2, 0.3]))
    v, w = np.array([0.3, -0.1, 0.2]), np.array([0.4, 0.2, -0.5])
    a = np.array([0.1, 0.5, -0.2]), np.array([-0.3, 0.1, 0.2])      # the twist's rate (v', w')
    columns = np.arange(6, dtype=np.int64)

    def pose(t):
        # a motion with twist (v + t v', w + t w') (w in the base frame) at t = 0
        return p0 + v * t + 0.5 * a[0] * t * t, exp_so3(w * t + 0.5 * a[1] * t * t) @ r0

    q, rows, qdot, bias, code, bar = B.rail_velocity_terms_kernel(bars, 6, *p0, tuple(r0.reshape(9)), (*v, *w),
                                                                  columns)
    assert (code, bar) == (B.VT_OK, -1)
    rates, code, bar = B.rail_jacobian_derivative_kernel(bars, 6, *p0, tuple(r0.reshape(9)), (*v, *w), columns)
    assert (code, bar) == (B.VT_OK, -1)
    np.testing.assert_allclose(q, ik(bars, p0, r0), rtol=0, atol=1e-15)
    h = 1e-5
    qs = [ik(bars, *pose(t)) for t in (-h, 0.0, h)]
    np.testing.assert_allclose(qdot, (qs[2] - qs[0]) / (2 * h), rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(rows @ np.concatenate([v, w]), qdot, rtol=1e-12)
    # q'' = J_m t' + J_m' t: the bias against the second difference
    qddot = (qs[2] - 2 * qs[1] + qs[0]) / h**2
    np.testing.assert_allclose(rows @ np.concatenate(a) + bias, qddot, rtol=1e-4, atol=1e-5)
    # the rows' rate against a central difference of J_m along the same motion
    def jac(t):
        p, r = pose(t)
        return B.rail_velocity_terms_kernel(bars, 6, *p, tuple(r.reshape(9)), (0.0,) * 6, columns)[1]
    np.testing.assert_allclose(rates, (jac(h) - jac(-h)) / (2 * h), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(rates @ np.concatenate([v, w]), bias, rtol=1e-12, atol=1e-12)


def test_a_rail_that_cannot_reach_and_a_bar_across_its_rail_are_named():
    bars = six_rail_machine()
    far = B.rail_velocity_terms_kernel(bars, 6, 10.0, 0.0, 0.0, (1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0), (0.0,) * 6,
                                       np.arange(6, dtype=np.int64))
    assert far[4] == B.VT_UNREACHABLE and 0 <= far[5] < 6
    # a bar exactly across its rail: the platform joint at the foot of the rail's normal, L away
    across = B.bar_rows([[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], actuator=[0], kind=B.RAIL, rail=[[1.0, 0.0, 0.0]],
                        length=[1.0], branch=[1.0])
    out = B.rail_velocity_terms_kernel(across, 1, 0.0, 1.0, 0.0, (1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0), (0.0,) * 6,
                                       np.array([0, 1, 2], dtype=np.int64))
    assert out[0][0] == 0.0 and (out[4], out[5]) == (B.VT_SINGULAR, 0)


def test_the_inline_6x6_determinant_is_numpys_with_its_sign():
    """``determinant6`` (the Gough branch check's det(J_h^-1), no LAPACK call) against
    numpy's det: random matrices, a row swap (sign), a singular matrix (0) and the
    unit pose Jacobian of the six-rail machine's bars."""
    rng = np.random.default_rng(5)
    for a in list(rng.normal(size=(50, 6, 6))) + [np.eye(6)[[1, 0, 2, 3, 4, 5]]]:
        assert np.isclose(B.determinant6(a.copy()), np.linalg.det(a), rtol=1e-12, atol=1e-14)
    singular = rng.normal(size=(6, 6))
    singular[3] = singular[1]
    assert abs(B.determinant6(singular.copy())) < 1e-12
    rows = np.empty((6, 6))
    assert B.unit_pose_jacobian_into(six_rail_machine(), 0.1, 0.0, 0.2, tuple(np.eye(3).reshape(9)), np.zeros(6),
                                     rows)
    assert np.isclose(B.determinant6(rows.copy()), np.linalg.det(rows), rtol=1e-12)
