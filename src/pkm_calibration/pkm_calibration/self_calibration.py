"""Self-calibration from redundancy (MoM3 §3: a machine whose encoders over-measure its
platform, dosr > 0): a planar machine on rails (ARCHI: four drives for three degrees of
freedom) identifies what its own encoders' inconsistency can identify, with no
instrument (pure).

Bar k (MACHINE_MODEL.md, ARCHI §3.1): its carriage at A_k = a_k + (q_k + z_k) u_k on
rail k, its platform joint B_k = p + R (b_k + db_k), its length L_k + dL_k; the closure

    r_ik = |p_i + R_i (b_k + db_k) - (a_k + da_k) - (q_ik + z_k) u_k| - (L_k + dL_k) = 0

at every reading i. Parameters per leg: dL_k, the encoder zero z_k, db_k (x, y, platform
frame), da_k's component across the rail (along it, it is the zero). The unknowns are
the parameters and every reading's pose (x, y, theta); the Jacobian of the residuals
in closed form, e = unit(B - A):

    dr/d(x, y) = e_xy,  dr/dtheta = e . (z x R b'),  dr/ddL = -1,  dr/dz = -e . u,
    dr/ddb = e^T R,  dr/dda_perp = -e . n  (n: the rail's normal in the plane)

Identifiability: the parameter columns with the poses' span projected out (what a
change of the parameters does that no change of the poses explains), then QR with
column pivoting (identify.identifiability): the rest are the redundancy's blind spots.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from pkm_kinematics import bars as B
from pkm_kinematics.errors import FieldError

from .identify import Identifiability, holding, identifiability

__all__ = ["PlanarRailErrorModel", "SelfCalibration", "self_calibrate"]


@dataclass(frozen=True)
class PlanarRailErrorModel:
    """A planar machine on rails (rails.RailMachine, task (x, y, theta)) and its error
    parameters (module doc). Constant; the methods take the parameters ``theta``."""

    machine: object
    names: tuple = field(init=False)

    def __post_init__(self):
        m = self.machine
        if m.task_space.name != "planar" or getattr(m, "bars", None) is None:
            raise FieldError("machine", f"{m.name}: self-calibration of a planar machine on rails (ARCHI), not "
                                        f"{type(m).__name__} ({m.task_space.name})")
        if m.n_legs <= 3:
            raise FieldError("machine", f"{m.name}: {m.n_legs} drives for 3 degrees of freedom: its encoders do not "
                                        "over-measure the platform (no redundancy to calibrate from)")
        names = [f"{p}.{leg}" for leg in m.leg_names for p in ("length", "zero", "b.x", "b.y", "rail.across")]
        object.__setattr__(self, "names", tuple(names))

    @property
    def size(self) -> int:
        return len(self.names)

    def residuals(self, theta, poses, readings) -> np.ndarray:
        """r_ik (N, n) of the closures (module doc)."""
        return self._terms(theta, poses, readings)[0]

    def _terms(self, theta, poses, readings):
        bars = self.machine.bars
        n = self.machine.n_legs
        t = np.asarray(theta, dtype=float).reshape(n, 5)
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        q = np.atleast_2d(np.asarray(readings, dtype=float))
        a, u = bars[:, B.COL_A:B.COL_A + 2], bars[:, B.COL_U:B.COL_U + 2]
        normal = np.column_stack((-u[:, 1], u[:, 0]))
        b = bars[:, B.COL_B:B.COL_B + 2] + t[:, 2:4]
        length = bars[:, B.COL_LENGTH] + t[:, 0]
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        rb = np.stack((c[:, None] * b[:, 0] - s[:, None] * b[:, 1], s[:, None] * b[:, 0] + c[:, None] * b[:, 1]),
                      axis=-1)                                              # (N, n, 2): R b'
        carriage = a + t[:, 4:5] * normal + (q + t[:, 1])[..., None] * u     # (N, n, 2)
        e = poses[:, None, :2] + rb - carriage
        norm = np.linalg.norm(e, axis=-1)
        return norm - length, e / norm[..., None], rb, u, normal, c, s

    def jacobian(self, theta, poses, readings) -> tuple[np.ndarray, np.ndarray]:
        """(d r / d poses, d r / d theta): (N n, 3 N) block-diagonal in the poses, (N n, size)."""
        _, e, rb, u, normal, c, s = self._terms(theta, poses, readings)
        N, n = e.shape[:2]
        d_pose = np.zeros((N * n, 3 * N))
        d_theta = np.zeros((N * n, self.size))
        for i in range(N):
            rows = slice(i * n, (i + 1) * n)
            d_pose[rows, 3 * i:3 * i + 2] = e[i]
            d_pose[rows, 3 * i + 2] = e[i, :, 0] * -rb[i, :, 1] + e[i, :, 1] * rb[i, :, 0]     # e . (z x R b')
            rot = np.array([[c[i], -s[i]], [s[i], c[i]]])
            for k in range(n):
                r = i * n + k
                d_theta[r, 5 * k] = -1.0
                d_theta[r, 5 * k + 1] = -e[i, k] @ u[k]
                d_theta[r, 5 * k + 2:5 * k + 4] = e[i, k] @ rot
                d_theta[r, 5 * k + 4] = -e[i, k] @ normal[k]
        return d_pose, d_theta

    def pose_blocks(self, poses, readings) -> np.ndarray:
        """Each reading's rows of d r / d theta at nominal with its pose's span projected
        out (N, n, size): what a change of the parameters does at that reading that no
        change of its pose explains (module doc; the closures' pose Jacobian is
        block-diagonal, so the projection is reading by reading)."""
        d_pose, d_theta = self.jacobian(np.zeros(self.size), poses, readings)
        n = self.machine.n_legs
        N = d_pose.shape[1] // 3
        pose = np.stack([d_pose[i * n:(i + 1) * n, 3 * i:3 * i + 3] for i in range(N)])
        blocks = d_theta.reshape(N, n, self.size)
        basis, _ = np.linalg.qr(pose)
        return blocks - basis @ np.einsum("nkj,nkl->njl", basis, blocks)

    def parameter_jacobian(self, poses, readings) -> np.ndarray:
        """d r / d theta at nominal with the poses' span projected out (pose_blocks, stacked)."""
        return self.pose_blocks(poses, readings).reshape(-1, self.size)

    def identifiability(self, poses, readings) -> Identifiability:
        """What the readings at ``poses`` identify."""
        return identifiability(self.parameter_jacobian(poses, readings), self.names)


@dataclass(frozen=True)
class SelfCalibration:
    theta: np.ndarray          # the parameters (the blind spots at nominal)
    poses: np.ndarray          # each reading's pose under them
    identifiable: Identifiability
    misfit_before_m: float     # RMS of the closures at the nominal model (its best poses)
    misfit_after_m: float
    std: np.ndarray            # the parameters' standard deviations from the encoders' noise (0: held)
    covariance: np.ndarray     # of the identified ones (identifiable.identified's order)


def self_calibrate(model: PlanarRailErrorModel, readings, guesses, max_nfev: int = 100,
                   held=None, sigma_m: float = 1e-6 / np.sqrt(12.0)) -> SelfCalibration:
    """The parameters and poses that close every bar at every reading (module doc), from
    the poses ``guesses`` (the poses commanded, or the nominal forward kinematics of the
    readings). ``held``: the blind spots' names to hold instead of the pivoting's choice
    (a convention: which parameter of a combination is held). ``sigma_m``: the encoders'
    noise (default a 1 um count's quantisation, 1/sqrt(12) um), for the standard
    deviations: sigma^2 (J^T J)^-1 of the poses and parameters together, J at the
    solution (a reading's closure moves with its encoder as dr/dq = -e . u)."""
    readings = np.atleast_2d(np.asarray(readings, dtype=float))
    guesses = np.atleast_2d(np.asarray(guesses, dtype=float))
    if readings.shape[1] != model.machine.n_legs or guesses.shape != (len(readings), 3):
        raise FieldError("readings", f"expected (N, {model.machine.n_legs}) readings and (N, 3) poses, got "
                                     f"{readings.shape} and {guesses.shape}")
    extra = len(readings) * (model.machine.n_legs - 3)
    if extra < model.size:
        least = -(-model.size // (model.machine.n_legs - 3))
        raise FieldError("readings", f"{len(readings)} readings over-measure the platform by {extra} for "
                                     f"{model.size} parameters: at least {least} poses")
    jacobian = model.parameter_jacobian(guesses, readings)
    which = identifiability(jacobian, model.names) if held is None else holding(jacobian, model.names, held)
    free = list(which.identified)
    N = len(readings)

    def unpack(z):
        theta = np.zeros(model.size)
        theta[free] = z[3 * N:]
        return z[:3 * N].reshape(N, 3), theta

    def fun(z):
        poses, theta = unpack(z)
        return model.residuals(theta, poses, readings).ravel()

    def jac(z):
        poses, theta = unpack(z)
        d_pose, d_theta = model.jacobian(theta, poses, readings)
        return np.hstack((d_pose, d_theta[:, free]))

    poses_only = least_squares(lambda z: model.residuals(np.zeros(model.size), z.reshape(N, 3), readings).ravel(),
                               guesses.ravel(), jac=lambda z: model.jacobian(np.zeros(model.size), z.reshape(N, 3),
                                                                             readings)[0],
                               xtol=1e-15, ftol=1e-15, gtol=1e-15)
    result = least_squares(fun, np.concatenate((poses_only.x, np.zeros(len(free)))), jac=jac, xtol=1e-15,
                           ftol=1e-15, gtol=1e-15, max_nfev=max_nfev)
    poses, theta = unpack(result.x)
    _, e, _, u, *_ = model._terms(theta, poses, readings)
    gain = np.abs(np.einsum("nkd,kd->nk", e, u)).ravel()          # |dr/dq| per closure
    full = jac(result.x) / gain[:, None]                           # in units of the encoders' noise
    cov = sigma_m ** 2 * np.linalg.pinv(full.T @ full)
    std = np.zeros(model.size)
    std[free] = np.sqrt(np.diag(cov)[3 * N:])
    rms = lambda r: float(np.sqrt(np.mean(r ** 2)))      # noqa: E731
    return SelfCalibration(theta, poses, which, rms(poses_only.fun), rms(result.fun), std, cov[3 * N:, 3 * N:])
