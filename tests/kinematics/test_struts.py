"""The strut machines (pkm_kinematics.struts on the bar kernels of
pkm_kinematics.bars): the Gough-Stewart hexapod of LinuxCNC's genhexkins and the
redundant 8-strut hexapod, as configurations only.

References: genhexkins' own algorithm re-derived here in numpy (its inverse, and its
Newton-Raphson forward kinematics that subtracts the step from the roll, pitch and
yaw words), scipy's least-squares solver for the redundant machine, finite
differences for J_m and its derivative, virtual work for the wrench map, and the
project's other models (the Gough metrology platform, the Delta's rails) for the
general bar kernels."""


import numpy as np
import pytest
from scipy.optimize import least_squares

from pkm_kinematics import ConfigError, JointLimitError, load_machine, load_machine_data
from pkm_kinematics import bars as B
from pkm_kinematics.struts import FKCode, StrutFK, rate_matrix
from pkm_kinematics.rotations import exp_so3, rotation_from_rpy

INCH = 0.0254
rng = np.random.default_rng(23)


def genhexkins():
    return load_machine("genhexkins").model


def hexapod8():
    return load_machine("hexapod8").model


# genhexkins.h, in inches: the base (b[i]) and platform (a[i]) joints
GH_BASE = np.array([[-22.95, 13.25, 0], [22.95, 13.25, 0], [22.95, 13.25, 0], [0, -26.5, 0], [0, -26.5, 0],
                    [-22.95, 13.25, 0]])
GH_PLATFORM = np.array([[-1.0, 11.5, 0], [1.0, 11.5, 0], [10.459, -4.884, 0], [9.459, -6.616, 0],
                        [-9.459, -6.616, 0], [-10.459, -4.884, 0]])


def gh_inverse(pose):
    """genhexKinematicsInverse: pose = (x, y, z in inches, a, b, c in degrees)."""
    rot = rotation_from_rpy(*np.radians(pose[3:]))
    return np.linalg.norm(pose[:3] + GH_PLATFORM @ rot.T - GH_BASE, axis=1)


def gh_forward(joints, pose, conv_criterion=1e-9, iter_limit=120):
    """genhexKinematicsForward: Newton-Raphson from ``pose``; the step of the rotation
    is subtracted from the roll, pitch and yaw words (radians) as they are."""
    trans, rpy = np.array(pose[:3], float), np.radians(pose[3:])
    for iteration in range(1, iter_limit + 1):
        rot = rotation_from_rpy(*rpy)
        ra = GH_PLATFORM @ rot.T
        strut = trans + ra - GH_BASE
        length = np.linalg.norm(strut, axis=1)
        unit = strut / length[:, None]
        inv_jac = np.hstack((unit, np.cross(ra, unit)))
        diff = length - joints
        delta = np.linalg.inv(inv_jac) @ diff
        trans -= delta[:3]
        rpy -= delta[3:]
        if np.all(np.abs(diff) <= conv_criterion):
            return np.concatenate((trans, np.degrees(rpy))), iteration
    raise AssertionError("genhexkins did not converge")


# poses in genhexkins' units: inches and degrees
GH_POSES = np.array([[0, 0, 20, 0, 0, 0], [1.5, -2.0, 21.0, 3.0, -4.0, 10.0], [-3.0, 2.5, 18.5, -8.0, 6.0, -12.0],
                     [3.9, 3.9, 22.9, 9.5, 9.5, 14.0], [0.2, -0.1, 17.2, 0.0, 0.0, 0.0]])


def to_task(pose):
    return np.concatenate((np.asarray(pose[:3]) * INCH, np.radians(pose[3:])))


@pytest.mark.parametrize("pose", GH_POSES.tolist())
def test_genhexkins_strut_lengths_point_for_point(pose):
    pose = np.array(pose)
    np.testing.assert_allclose(genhexkins().inverse_kinematics(to_task(pose)) / INCH, gh_inverse(pose),
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("pose", GH_POSES[1:].tolist())
def test_genhexkins_forward_kinematics_agrees_with_its_algorithm(pose):
    machine, pose = genhexkins(), np.array(pose)
    joints = gh_inverse(pose)
    # both from genhexkins' own start, the pose of the previous cycle: here home
    theirs, _ = gh_forward(joints, GH_POSES[0])
    ours = machine.forward_kinematics(joints * INCH, guess=to_task(GH_POSES[0]))
    assert ours.code == FKCode.CONVERGED and ours.iterations <= 8
    np.testing.assert_allclose(ours.x[:3] / INCH, theirs[:3], rtol=0, atol=1e-8)     # inches
    np.testing.assert_allclose(np.degrees(ours.x[3:]), theirs[3:], rtol=0, atol=1e-8)
    np.testing.assert_allclose(ours.x[:3] / INCH, pose[:3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.degrees(ours.x[3:]), pose[3:], rtol=0, atol=1e-9)


def test_a_warm_stream_converges_in_two_iterations_and_a_failure_keeps_the_warm_start():
    machine = genhexkins()
    fk = StrutFK(machine)
    t = np.linspace(0.0, 1.0, 200)
    path = np.column_stack((0.05 * np.sin(2 * np.pi * t), 0.03 * np.cos(2 * np.pi * t) - 0.03, 0.51 + 0.02 * t,
                            0.1 * np.sin(2 * np.pi * t), 0.05 * t, 0.2 * t))
    iterations = []
    for x in path:
        result = fk.solve(machine.inverse_kinematics(x))
        assert result.ok
        np.testing.assert_allclose(result.x, x, rtol=0, atol=1e-10)
        iterations.append(result.iterations)
    assert max(iterations[2:]) <= 2, iterations       # 1.5 mm a reading
    # at 2 kHz the guess extrapolated from the last two poses is one Newton step away;
    # the last pose alone is two (reset between readings: no previous pose)
    t = np.arange(20) * 5e-4                      # 2 kHz, ~100 um and ~0.1 mrad a reading
    fine = np.column_stack((0.05 * np.sin(4 * t), 0.2 * t, 0.55 + 0.1 * t, 0.2 * t, -0.1 * t, 0.3 * np.sin(t)))
    fk.reset(fine[0])
    extrapolated = [fk.solve(machine.inverse_kinematics(x)).iterations for x in fine]
    assert extrapolated[2:] == [1] * 18, extrapolated
    last_only = []
    for a, b in zip(fine[:-1], fine[1:]):
        fk.reset(a)
        last_only.append(fk.solve(machine.inverse_kinematics(b)).iterations)
    assert min(last_only) == 2, last_only
    bad = fk.solve(np.full(6, 5.0))                                  # no pose: 5 m struts on 0.3 m joints
    assert not bad.ok and bad.code in (FKCode.DIVERGED, FKCode.STALLED, FKCode.NO_CONVERGENCE, FKCode.SINGULAR)
    again = fk.solve(machine.inverse_kinematics(fine[-1]))
    assert again.ok and again.iterations == 0       # from the last good pose


def test_the_redundant_hexapod_forward_kinematics_is_the_least_squares_pose():
    machine = hexapod8()
    x = np.array([0.04, -0.03, 0.63, 0.05, -0.08, 0.12])
    q = machine.inverse_kinematics(x)
    exact = machine.forward_kinematics(q)
    assert exact.ok and exact.misfit_m < 1e-12
    np.testing.assert_allclose(exact.x, x, rtol=0, atol=1e-11)
    # inconsistent readings (noise, and one encoder 0.5 mm off): the least-squares pose
    noisy = q + rng.normal(0.0, 2e-5, 8)
    noisy[5] += 5e-4
    ours = machine.forward_kinematics(noisy)
    p0, r0 = machine.pose(machine.home)

    def residuals(z):
        rot = exp_so3(z[3:]) @ r0
        return np.linalg.norm(z[:3] + machine.platform_joints @ rot.T - machine.base_joints, axis=1) - noisy
    ref = least_squares(residuals, np.concatenate((p0, np.zeros(3))), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    ref_rot = exp_so3(ref.x[3:]) @ r0
    assert ours.ok
    np.testing.assert_allclose(ours.position, ref.x[:3], rtol=0, atol=1e-10)
    np.testing.assert_allclose(ours.rotation, ref_rot, rtol=0, atol=1e-10)
    assert ours.misfit_m == pytest.approx(np.linalg.norm(ref.fun), rel=1e-6)
    assert ours.misfit_m > 1e-4                                     # the 0.5 mm encoder shows


@pytest.mark.parametrize("which", ["genhexkins", "hexapod8"])
def test_jacobian_and_its_derivative_against_finite_differences(which):
    machine = load_machine(which).model
    lo = machine.workspace["center"] - machine.workspace["half_size"]
    hi = machine.workspace["center"] + machine.workspace["half_size"]
    for _ in range(5):
        x = np.concatenate((rng.uniform(lo, hi), np.radians(rng.uniform(-8, 8, 3))))
        twist = rng.normal(0.0, 0.1, 6)
        p, rot = machine.pose(x)
        h = 1e-6

        def lengths(s):
            """Strut lengths after moving along the twist for s seconds."""
            return machine.strut_lengths(p + s * twist[:3], exp_so3(s * twist[3:]) @ rot)
        q_dot = (lengths(h) - lengths(-h)) / (2 * h)
        np.testing.assert_allclose(machine.jacobian(x) @ twist, q_dot, rtol=0, atol=1e-8)
        # task rates: x' = (v, a', b', c'), w = E (a', b', c')
        rates = rng.normal(0.0, 0.1, 6)
        fd = (machine.inverse_kinematics(x + h * rates, False) - machine.inverse_kinematics(x - h * rates, False)) \
            / (2 * h)
        np.testing.assert_allclose(machine.task_jacobian(x) @ rates, fd, rtol=0, atol=1e-8)

        def jac_along(s):
            ps, rs = p + s * twist[:3], exp_so3(s * twist[3:]) @ rot
            return machine.jacobian(machine.task_coordinates(ps, rs))
        jdot = (jac_along(h) - jac_along(-h)) / (2 * h)
        np.testing.assert_allclose(machine.jacobian_derivative(x, twist), jdot, rtol=0, atol=1e-7)


def test_rate_matrix_is_the_angular_velocity_of_the_abc_rates():
    abc, rates, h = np.array([0.3, -0.4, 1.1]), np.array([0.2, 0.5, -0.7]), 1e-6
    r_dot = (rotation_from_rpy(*(abc + h * rates)) - rotation_from_rpy(*(abc - h * rates))) / (2 * h)
    omega = r_dot @ rotation_from_rpy(*abc).T                         # [w]x
    np.testing.assert_allclose(rate_matrix(*abc) @ rates, [omega[2, 1], omega[0, 2], omega[1, 0]], atol=1e-9)


@pytest.mark.parametrize("which", ["genhexkins", "hexapod8"])
def test_wrench_map_and_internal_forces(which):
    machine = load_machine(which).model
    x = machine.home + np.array([0.01, -0.02, 0.01, 0.05, 0.02, -0.1])
    wrench_map, twist, forces = machine.wrench_map(x), rng.normal(size=6), rng.normal(size=machine.n_legs)
    # virtual work: f . q' = F . t
    assert forces @ (machine.jacobian(x) @ twist) == pytest.approx((wrench_map @ forces) @ twist, rel=1e-12)
    basis = machine.internal_force_basis(x)
    assert basis.shape == (machine.n_legs, machine.n_legs - 6)
    if basis.size:
        np.testing.assert_allclose(wrench_map @ basis, 0.0, atol=1e-12)


def test_the_general_bar_kernels_reproduce_the_gough_metrology_and_the_delta_rails():
    """The bar model on the other machines' data: the MoM3 Gough platform as 6
    struts (its strut lengths and J_h^-1 against numpy's formulas: |p + R b - a| and
    the rows [u, (R b) x u]), and the MoM3 Delta's rails (its IK: one bar per
    carriage, the platform translating)."""
    cfg = load_machine("mom3")
    gough = cfg.metrology.platform
    bars = B.bar_rows(gough.base_points, gough.plate_points, actuator=np.arange(6), kind=B.STRUT)
    np.testing.assert_array_equal(gough.bars, bars)
    p, rot = np.array([0.02, -0.03, 0.80]), rotation_from_rpy(0.05, -0.04, 0.1)
    q = np.empty(6)
    assert B.inverse_kinematics_into(bars, p, rot.reshape(9).copy(), q) == (B.IK_OK, -1)
    rb = gough.plate_points @ rot.T
    struts = p + rb - gough.base_points
    np.testing.assert_allclose(q, np.linalg.norm(struts, axis=1), rtol=0, atol=1e-15)
    np.testing.assert_allclose(gough.strut_lengths(p, rot), q, rtol=0, atol=1e-15)
    u = struts / np.linalg.norm(struts, axis=1)[:, None]
    np.testing.assert_allclose(gough.inverse_jacobian(p, rot), np.hstack([u, np.cross(rb, u)]), rtol=0, atol=1e-14)

    delta = cfg.model
    legs = delta.legs
    rails = B.bar_rows([leg.rail_origin for leg in legs], [leg.platform_point for leg in legs],
                       actuator=np.arange(3), kind=B.RAIL, rail=[leg.rail_direction for leg in legs],
                       length=[leg.link_length for leg in legs], branch=[leg.assembly for leg in legs])
    for position in (delta.home, delta.home + np.array([0.1, -0.12, 0.08])):
        q = np.empty(3)
        assert B.inverse_kinematics_into(rails, position, np.eye(3).reshape(9), q)[0] == B.IK_OK
        np.testing.assert_allclose(q, delta.inverse_kinematics(position), rtol=0, atol=1e-12)
    far = np.empty(3)
    code, bar = B.inverse_kinematics_into(rails, delta.home + np.array([2.0, 0.0, 0.0]), np.eye(3).reshape(9), far)
    assert code == B.IK_UNREACHABLE and bar in (0, 1, 2)


def test_limits_and_bad_configurations_are_named():
    machine = genhexkins()
    with pytest.raises(JointLimitError, match=r"j\d: .* outside its limits"):
        machine.inverse_kinematics(machine.home + np.array([0.0, 0.0, 0.6, 0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="q: expected 6 finite positive strut lengths"):
        machine.forward_kinematics([0.7] * 5)
    import yaml
    from pkm_kinematics.config import config_dir
    data = yaml.safe_load((config_dir() / "machines" / "hexapod8.yaml").read_text())
    five = {**data, "struts": data["struts"][:5]}
    with pytest.raises(ConfigError, match=r"struts: expected a list of at least 6 entries"):
        load_machine_data(five)
    inches = {**data, "length_unit": "furlong"}
    with pytest.raises(ConfigError, match=r"length_unit: must be one of \['m', 'mm', 'inch'\], got 'furlong'"):
        load_machine_data(inches)
    # every strut to the platform's centre: the platform may turn freely, nothing holds it
    flat = {**data, "struts": [{**s, "platform": [0.0, 0.0, 0.0]} for s in data["struts"]]}
    with pytest.raises(ConfigError, match=r"struts: the struts do not hold the platform at home: J_m is singular"):
        load_machine_data(flat)
    short = {**data, "home": {"position": [0.0, 0.0, 0.2]}}
    with pytest.raises(ConfigError, match=r"home: s1: .* outside its limits"):
        load_machine_data(short)


def test_the_compiled_stream_gives_the_per_call_solves():
    machine = hexapod8()
    t = np.linspace(0.0, 0.5, 120)
    path = np.column_stack((0.05 * np.sin(4 * t), 0.02 * t, 0.6 + 0.03 * t, 0.05 * t, -0.04 * t, 0.1 * np.sin(t)))
    lengths = np.array([machine.inverse_kinematics(x) for x in path])
    lengths[60] = 3.0                                                 # one impossible reading in the stream
    per_call, stream = StrutFK(machine), StrutFK(machine)
    poses, codes, iterations, misfits = stream.solve_stream(lengths)
    for k, q in enumerate(lengths):
        one = per_call.solve(q)
        assert codes[k] == one.code and iterations[k] == one.iterations, k
        if one.ok:
            np.testing.assert_array_equal(poses[k, :3], one.position)
            np.testing.assert_array_equal(poses[k, 3:].reshape(3, 3), one.rotation)
            np.testing.assert_allclose(machine.task_coordinates(poses[k, :3], poses[k, 3:].reshape(3, 3)), path[k],
                                       rtol=0, atol=1e-10)
    assert codes[60] != FKCode.CONVERGED and (np.delete(codes, 60) == FKCode.CONVERGED).all()


def test_a_strut_machines_dynamics_section_is_read_as_rigid_body_parameters_and_checked():
    import yaml

    from pkm_kinematics import config_dir
    from pkm_kinematics.rigid_body import RigidBodyParameters
    data = yaml.safe_load((config_dir() / "machines" / "genhexkins.yaml").read_text())
    params = load_machine_data(data).dynamics
    assert isinstance(params, RigidBodyParameters) and params.drive_mass_kg == (2.0,) * 6
    assert np.diag(np.reshape(params.platform_inertia_kgm2, (3, 3))).tolist() == [0.4, 0.4, 0.7]
    data["dynamics"]["platform_inertia_kgm2"] = [0.4, -1.0, 0.7]
    with pytest.raises(ConfigError, match=r"dynamics.platform_inertia_kgm2: must be 3 positive numbers"):
        load_machine_data(data)
