"""The 6-DOF platform's rigid-body dynamics (pkm_kinematics.rigid_body) on the
redundant hexapod: energy conserved along a free motion (RK4, drives unpowered,
no friction: the platform falls and tumbles), equilibrium under the static forces,
forward and inverse dynamics each other's inverse, friction dissipating."""

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics import distribution as fd
from pkm_kinematics.rigid_body import RigidBodyParameters, StrutDynamics
from pkm_kinematics.rotations import exp_so3


def model(friction=0.0):
    machine = load_machine("hexapod8").model
    params = RigidBodyParameters(platform_mass_kg=12.0, platform_inertia_kgm2=np.diag([0.15, 0.18, 0.25]),
                                 drive_mass_kg=(3.0,) * 8, friction_ns_per_m=(friction,) * 8)
    return StrutDynamics(machine, params)


def integrate(dyn, x0, t0, seconds, dt, forces=None):
    """RK4 on (p, R, t): p' = v, R' = [w]x R (R advanced by exp over each stage)."""
    machine = dyn.machine
    p, rot = machine.pose(x0)
    t = np.array(t0, dtype=float)
    forces = np.zeros(machine.n_legs) if forces is None else forces

    def accel(p_, r_, t_):
        return dyn.forward_dynamics(machine.task_coordinates(p_, r_), t_, forces)

    energies = [dyn.energy(x0, t)]
    for _ in range(int(round(seconds / dt))):
        k1v, k1a = t, accel(p, rot, t)
        p2, r2 = p + 0.5 * dt * k1v[:3], exp_so3(0.5 * dt * k1v[3:]) @ rot
        k2v = t + 0.5 * dt * k1a
        k2a = accel(p2, r2, k2v)
        p3, r3 = p + 0.5 * dt * k2v[:3], exp_so3(0.5 * dt * k2v[3:]) @ rot
        k3v = t + 0.5 * dt * k2a
        k3a = accel(p3, r3, k3v)
        p4, r4 = p + dt * k3v[:3], exp_so3(dt * k3v[3:]) @ rot
        k4v = t + dt * k3a
        k4a = accel(p4, r4, k4v)
        velocity = (k1v + 2 * k2v + 2 * k3v + k4v) / 6.0
        p, rot = p + dt * velocity[:3], exp_so3(dt * velocity[3:]) @ rot
        t = t + dt * (k1a + 2 * k2a + 2 * k3a + k4a) / 6.0
        energies.append(dyn.energy(machine.task_coordinates(p, rot), t))
    return machine.task_coordinates(p, rot), t, np.array(energies)


def test_energy_is_conserved_along_a_free_tumbling_fall():
    dyn = model()
    x0 = dyn.machine.home + np.array([0.01, -0.02, 0.03, 0.05, -0.04, 0.1])
    x, t, energy = integrate(dyn, x0, [0.05, -0.1, 0.2, 0.8, -0.5, 1.2], 0.15, 5e-4)
    assert np.linalg.norm(x[:3] - x0[:3]) > 0.02                          # it moved: fell and turned
    assert np.ptp(energy) < 1e-8 * (abs(energy[0]) + 1.0), np.ptp(energy)


def test_a_free_platform_keeps_its_angular_momentum():
    """Massless drives, no gravity, no forces: a free rigid body, whose angular momentum
    I_w w is constant in the base frame while w itself precesses (the Euler term's
    work is zero, so only this sees it)."""
    machine = load_machine("hexapod8").model
    free = StrutDynamics(machine, RigidBodyParameters(12.0, np.diag([0.15, 0.18, 0.25]), (0.0,) * 8, (0.0,) * 8,
                                                      (0.0, 0.0, 0.0)))
    t0 = np.array([0.0, 0.0, 0.0, 0.9, -0.6, 1.5])
    x, t, _ = integrate(free, machine.home, t0, 0.2, 5e-4)
    momentum0 = free.inertia_world(machine.home) @ t0[3:]
    np.testing.assert_allclose(free.inertia_world(x) @ t[3:], momentum0, rtol=0, atol=1e-9)
    assert np.linalg.norm(t[3:] - t0[3:]) > 1e-2                          # w itself changed


def test_friction_dissipates():
    dyn = model(friction=200.0)
    _, _, energy = integrate(dyn, dyn.machine.home, [0.0, 0.0, 0.3, 0.5, 0.0, 0.0], 0.05, 5e-4)
    assert (np.diff(energy) < 1e-12).all() and energy[-1] < energy[0] - 1e-3


def test_the_static_forces_hold_the_platform_still():
    dyn = model()
    x = dyn.machine.home + np.array([0.03, 0.02, -0.04, 0.06, 0.02, -0.1])
    load = np.array([50.0, -20.0, -300.0, 4.0, 2.0, -6.0])
    wrench = dyn.static_forces(x, load)
    np.testing.assert_allclose(wrench[:3], -12.0 * np.array([0.0, 0.0, -9.81]) - load[:3], rtol=1e-12)
    np.testing.assert_allclose(wrench[3:], -load[3:], rtol=1e-12)        # the weight acts at p: no moment
    forces = fd.min_inf_norm(dyn.machine.jacobian(x), wrench)
    np.testing.assert_allclose(dyn.forward_dynamics(x, np.zeros(6), forces, load), 0.0, atol=1e-9)


def test_forward_and_inverse_dynamics_are_each_others_inverse():
    dyn = model(friction=30.0)
    rng = np.random.default_rng(5)
    x = dyn.machine.home + np.array([-0.02, 0.01, 0.02, -0.03, 0.05, 0.2])
    t, forces = rng.normal(0.0, 0.3, 6), rng.normal(0.0, 200.0, 8)
    accel = dyn.forward_dynamics(x, t, forces)
    np.testing.assert_allclose(dyn.inverse_dynamics(x, t, accel), dyn.machine.jacobian(x).T @ forces,
                               rtol=1e-10, atol=1e-9)


def test_bad_parameters_are_named():
    machine = load_machine("hexapod8").model
    with pytest.raises(ValueError, match="drive_mass_kg and friction_ns_per_m need 8 entries"):
        StrutDynamics(machine, RigidBodyParameters(10.0, np.eye(3), (1.0,) * 6, (0.0,) * 6))
    with pytest.raises(ValueError, match="platform_inertia_kgm2: must be symmetric positive definite"):
        StrutDynamics(machine, RigidBodyParameters(10.0, -np.eye(3), (1.0,) * 8, (0.0,) * 8))
