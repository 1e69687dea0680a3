"""Calibrating a machine on rails (rail_errors.RailErrorModel): the parameters and every
reading's pose together, by nonlinear least squares on the closures of its bars and,
with an instrument, its readings of the tool point (pure).

Self-calibration from redundancy (MoM3 §3: a machine whose encoders over-measure its
platform, dosr > 0): a planar machine on rails with more drives than degrees of
freedom (ARCHI: four for three) identifies what its own encoders' inconsistency can
identify, with no instrument (``PlanarRailErrorModel``, ``self_calibrate``). With an
instrument (a laser tracker, the Gough metrology: ``calibrate_rails`` with its points)
the same machine, or one without redundancy (MoM3's Delta), identifies more.

Each row is weighted by its noise (the encoders' count for a closure, the instrument's
sigma for a point), so that the standard deviations sigma^2 (J^T J)^-1 of the poses
and parameters together, J at the solution, are the parameters' (a reading's closure
moves with its encoder as dr/dq = -e . u).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from pkm_kinematics.errors import FieldError

from .identify import Identifiability, holding, identifiability
from .rail_errors import RailErrorModel

__all__ = ["PlanarRailErrorModel", "RailCalibration", "SelfCalibration", "calibrate_rails", "self_calibrate"]

ENCODER_NOISE_M = 1e-6 / np.sqrt(12.0)     # a 1 um count's quantisation


@dataclass(frozen=True)
class PlanarRailErrorModel(RailErrorModel):
    """A planar machine on rails whose encoders over-measure its platform (more drives
    than its three degrees of freedom): the model of self-calibration (module doc)."""

    def __post_init__(self):
        m = self.machine
        if m.task_space.name != "planar" or getattr(m, "bars", None) is None:
            raise FieldError("machine", f"{m.name}: self-calibration of a planar machine on rails (ARCHI), not "
                                        f"{type(m).__name__} ({m.task_space.name})")
        if m.n_legs <= 3 and not self.instrument:
            raise FieldError("machine", f"{m.name}: {m.n_legs} drives for 3 degrees of freedom: its encoders do not "
                                        "over-measure the platform (no redundancy to calibrate from)")
        super().__post_init__()


@dataclass(frozen=True)
class RailCalibration:
    theta: np.ndarray          # the parameters (the held ones at nominal)
    poses: np.ndarray          # each reading's pose under them
    identifiable: Identifiability
    misfit_before_m: float     # RMS of the closures and points at the nominal model (its best poses)
    misfit_after_m: float
    std: np.ndarray            # the parameters' standard deviations (0: held)
    covariance: np.ndarray     # of the identified ones (identifiable.identified's order)


SelfCalibration = RailCalibration


def calibrate_rails(model: RailErrorModel, readings, guesses, points=None, sigma_m: float = ENCODER_NOISE_M,
                    point_sigma_m: float = 1e-6, held=None, max_nfev: int = 100) -> RailCalibration:
    """The parameters and poses that close every bar at every reading and, with
    ``points`` (N, 2 or 3: the instrument's), explain what it read (module doc); from
    the poses ``guesses`` (the poses commanded, or the nominal forward kinematics of the
    readings). ``sigma_m``, ``point_sigma_m``: the encoders' and the instrument's noise.
    ``held``: names to hold instead of the pivoting's choice (which parameter of a
    combination is held is a convention)."""
    readings = np.atleast_2d(np.asarray(readings, dtype=float))
    guesses = np.atleast_2d(np.asarray(guesses, dtype=float))
    n, N = model.machine.n_legs, len(readings)
    if readings.shape[1] != n or guesses.shape != (N, 3):
        raise FieldError("readings", f"expected (N, {n}) readings and (N, 3) poses, got {readings.shape} and "
                                     f"{guesses.shape}")
    if model.instrument != (points is not None):
        raise FieldError("points", "an instrument's points go with a model of the instrument, and only then")
    d = model.readings_per_point if points is not None else 0
    if points is not None:
        points = np.atleast_2d(np.asarray(points, dtype=float))[:, :d]
        if points.shape != (N, d):
            raise FieldError("points", f"expected one point ({d} coordinates) per reading ({N}), got shape "
                                       f"{points.shape}")
    extra = N * (n + d - 3)
    if extra < model.size:
        least = -(-model.size // (n + d - 3))
        raise FieldError("readings", f"{N} readings over-measure the platform by {extra} for {model.size} "
                                     f"parameters: at least {least} poses")
    scales = (sigma_m, point_sigma_m)
    jacobian = model.parameter_jacobian(guesses, readings, scales)
    which = identifiability(jacobian, model.names) if held is None else holding(jacobian, model.names, held)
    free = list(which.identified)

    def unpack(z):
        theta = np.zeros(model.size)
        theta[free] = z[3 * N:]
        return z[:3 * N].reshape(N, 3), theta

    # each closure's noise is its encoder's, |dr/dq| = |e . u| times sigma_m (at the
    # guesses' nominal poses: fixed weights, so that the covariance below is the
    # estimator's), a point's the instrument's
    _, e, _, u, *_ = model._terms(np.zeros(model.size), guesses, readings)
    weight = 1.0 / (sigma_m * np.maximum(np.abs(np.einsum("nkd,kd->nk", e, u)).ravel(), 1e-3))

    def fun_of(poses, theta):
        r = model.residuals(theta, poses, readings).ravel() * weight
        if points is None:
            return r
        return np.concatenate((r, (model.points(theta, poses) - points).ravel() / point_sigma_m))

    def jac_of(poses, theta, columns):
        d_pose, d_theta = model.jacobian(theta, poses, readings)
        rows = np.hstack((d_pose, d_theta[:, columns])) * weight[:, None]
        if points is None:
            return rows
        y_pose, y_theta = model.point_jacobian(theta, poses)
        return np.vstack((rows, np.hstack((y_pose, y_theta[:, columns])) / point_sigma_m))

    zero = np.zeros(model.size)
    poses_only = least_squares(lambda z: fun_of(z.reshape(N, 3), zero), guesses.ravel(),
                               jac=lambda z: jac_of(z.reshape(N, 3), zero, []), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    result = least_squares(lambda z: fun_of(*unpack(z)), np.concatenate((poses_only.x, np.zeros(len(free)))),
                           jac=lambda z: jac_of(*unpack(z), free), xtol=1e-15, ftol=1e-15, gtol=1e-15,
                           max_nfev=max_nfev)
    poses, theta = unpack(result.x)
    full = jac_of(poses, theta, free)
    cov = np.linalg.pinv(full.T @ full)
    std = np.zeros(model.size)
    std[free] = np.sqrt(np.diag(cov)[3 * N:])

    def rms(z, x):                       # in metres: the closures' and the points' rows
        r = fun_of(z, x)
        r[:N * n] /= weight
        r[N * n:] *= point_sigma_m
        return float(np.sqrt(np.mean(r ** 2)))
    return RailCalibration(theta, poses, which, rms(poses_only.x.reshape(N, 3), zero), rms(poses, theta), std,
                           cov[3 * N:, 3 * N:])


def self_calibrate(model: PlanarRailErrorModel, readings, guesses, max_nfev: int = 100, held=None,
                   sigma_m: float = ENCODER_NOISE_M) -> RailCalibration:
    """Self-calibration from the redundancy: calibrate_rails with no instrument."""
    return calibrate_rails(model, readings, guesses, sigma_m=sigma_m, held=held, max_nfev=max_nfev)
