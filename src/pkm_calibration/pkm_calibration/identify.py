"""Identifiability and identification (pure): which parameters the measurements can
identify, and their values from a set of readings by nonlinear least squares.

- ``identifiability``: the identification Jacobian's columns scaled to unit norm, QR with
  column pivoting (Businger & Golub 1965; its use for calibration: Hollerbach & Wampler,
  "The calibration index and taxonomy for robot kinematic calibration methods", IJRR
  1996): the first ``rank`` pivots are identified, the others are combinations of them
  (held at nominal, named). Rank by |R_ii| > ``RANK_TOLERANCE`` |R_00|.
- ``identify``: scipy's least_squares (trust region) on the identifiable parameters from
  the nominal ones, the model's closed-form Jacobian; the parameters' standard deviations
  from the measurement noise sigma, sigma^2 (J^T J)^-1 at the solution; the residuals'
  RMS before and after.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import qr
from scipy.optimize import least_squares

from pkm_kinematics.errors import FieldError

__all__ = ["Identifiability", "Identification", "gauge", "holding", "identifiability", "identify", "RANK_TOLERANCE"]

RANK_TOLERANCE = 1e-8


@dataclass(frozen=True)
class Identifiability:
    identified: tuple          # indices of the parameters the measurements identify
    held: tuple                # the others (their combinations with the identified ones), held at nominal
    names: tuple               # every parameter's name
    condition: float           # of the identified columns, scaled

    def describe(self) -> str:
        held = ", ".join(self.names[k] for k in self.held) or "none"
        return (f"{len(self.identified)} of {len(self.names)} parameters identifiable (condition "
                f"{self.condition:.3g}); held at nominal: {held}")


@dataclass(frozen=True)
class Identification:
    theta: np.ndarray          # every parameter (the held ones at nominal: 0)
    std: np.ndarray            # their standard deviations (0 for the held ones)
    covariance: np.ndarray     # of the identified ones (identifiable.identified's order), m^2 ...
    identifiable: Identifiability
    rms_before_m: float        # the readings' residuals with the nominal model
    rms_after_m: float         # and with the identified one
    iterations: int


def identifiability(jacobian, names) -> Identifiability:
    """What the measurements identify (module doc)."""
    jac = np.asarray(jacobian, dtype=float)
    if jac.ndim != 2 or jac.shape[1] != len(names):
        raise FieldError("jacobian", f"expected (measurements, {len(names)}), got shape {jac.shape}")
    if jac.shape[0] < jac.shape[1]:
        raise FieldError("poses", f"{jac.shape[0]} measurements for {jac.shape[1]} parameters: too few poses "
                                  f"(at least {int(np.ceil(jac.shape[1] / 3))} readings of a point)")
    norms = np.linalg.norm(jac, axis=0)
    scaled = jac / np.where(norms > 0.0, norms, 1.0)
    _, r, pivots = qr(scaled, pivoting=True, mode="economic")
    diag = np.abs(np.diag(r))
    rank = int(np.sum(diag > RANK_TOLERANCE * diag[0]))
    keep = tuple(sorted(int(k) for k in pivots[:rank]))
    s = np.linalg.svd(scaled[:, list(keep)], compute_uv=False)
    return Identifiability(keep, tuple(sorted(int(k) for k in pivots[rank:])), tuple(names), float(s[0] / s[-1]))


def gauge(jacobian, names, first=()) -> tuple:
    """A convention for what is held at nominal, the same for any measurements that are
    not special: the parameters named ``first``, then, in the parameters' order, each one
    that adds nothing the ones before it do not already explain (its column, scaled to
    unit norm, in the span of the earlier ones within 1e3 RANK_TOLERANCE), so that a
    simulation's truth and its identification agree on them."""
    jac = np.asarray(jacobian, dtype=float)
    jac = jac / np.where(np.linalg.norm(jac, axis=0) > 0.0, np.linalg.norm(jac, axis=0), 1.0)
    held = []
    basis = np.zeros((jac.shape[0], 0))
    for k, name in enumerate(names):
        if name in first:
            continue
        residual = jac[:, k] - basis @ (basis.T @ jac[:, k])
        if np.linalg.norm(residual) > 1e3 * RANK_TOLERANCE:
            basis = np.column_stack((basis, residual / np.linalg.norm(residual)))
        else:
            held.append(name)
    return tuple(n for n in names if n in first) + tuple(held)


def holding(jacobian, names, held) -> Identifiability:
    """The identifiability with the parameters named ``held`` held at nominal instead of
    the pivoting's choice; FieldError naming an unknown name, or the parameters the rest
    still cannot identify."""
    unknown = [name for name in held if name not in names]
    if unknown:
        raise FieldError("held", f"{unknown[0]!r} is not a parameter (e.g. {names[0]})")
    rest = tuple(k for k, name in enumerate(names) if name not in held)
    check = identifiability(np.asarray(jacobian)[:, list(rest)], [names[k] for k in rest])
    if check.held:
        raise FieldError("held", f"with {len(held)} held, {', '.join(check.names[k] for k in check.held)} "
                                 "still cannot be identified")
    return Identifiability(rest, tuple(k for k, name in enumerate(names) if name in held), tuple(names),
                           check.condition)


def identify(model, readings, measured, sigma_m: float, guesses=None, max_nfev: int = 50,
             held=None) -> Identification:
    """The parameters of ``model`` (strut_errors.StrutErrorModel) that best explain the
    instrument's ``measured`` points (N, 3) at the encoder ``readings`` (N, n): the
    identifiable ones by least squares, the others held at nominal (module doc).
    ``held``: the names to hold instead of the pivoting's choice (which of a
    non-identifiable combination's parameters is held is a convention); the rest must
    then be identifiable, or FieldError names the combination left."""
    readings = np.atleast_2d(np.asarray(readings, dtype=float))
    measured = np.atleast_2d(np.asarray(measured, dtype=float))
    if measured.shape != (len(readings), 3):
        raise FieldError("measured", f"expected one point (x, y, z) per reading ({len(readings)}), got shape "
                                     f"{measured.shape}")
    if not sigma_m > 0.0:
        raise FieldError("sigma_m", f"the instrument's noise must be > 0 m, got {sigma_m}")
    nominal = np.zeros(model.size)
    prediction = model.predict(nominal, readings, guesses)
    jacobian = model.jacobian(nominal, readings, prediction)
    which = identifiability(jacobian, model.names)
    if held is not None:
        which = holding(jacobian, model.names, held)
    free = list(which.identified)

    def full(x):
        theta = nominal.copy()
        theta[free] = x
        return theta

    state = {}

    def residual(x):
        state["prediction"] = model.predict(full(x), readings, guesses)
        return (state["prediction"].y - measured).ravel()

    def jac(x):
        return model.jacobian(full(x), readings, state.get("prediction"))[:, free]

    before = residual(np.zeros(len(free)))
    result = least_squares(residual, np.zeros(len(free)), jac=jac, method="trf", x_scale="jac", max_nfev=max_nfev,
                           xtol=1e-15, ftol=1e-15, gtol=1e-15)
    theta = full(result.x)
    after = residual(result.x)
    j_free = model.jacobian(theta, readings, state["prediction"])[:, free]
    cov = sigma_m ** 2 * np.linalg.inv(j_free.T @ j_free)
    std = np.zeros(model.size)
    std[free] = np.sqrt(np.diag(cov))
    return Identification(theta, std, cov, which, float(np.sqrt(np.mean(before ** 2))),
                          float(np.sqrt(np.mean(after ** 2))), int(result.nfev))
