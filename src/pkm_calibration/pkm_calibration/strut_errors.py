"""The error model of a machine on struts (the bar model's strut case, MoM3 eq. 1,
genhexkins) measured by an external instrument, and its identification Jacobian.

Parameters (deltas from the nominal machine file, SI units), in this order:

    a_k   (3 per strut)  the base joint:      A_k = a_k + da_k
    b_k   (3 per strut)  the platform joint:  B_k = p + R (b_k + db_k)
    z_k   (1 per strut)  the encoder's zero:   l_k = q_k + z_k + s_k q_k
    s_k   (1 per strut)  its scale (a pitch error)
    frame (6)            the instrument's frame in the base frame: its origin and
                         rotation vector (Rodrigues), nominal at the base frame

The instrument reads the tool point t (platform frame) in its own frame:
y = R_T^T (p + R t - p_T). A reading's pose (p, R) closes every strut: |B_k - A_k| = l_k
(forward kinematics of the identified geometry, ``StrutMachine``).

The identification Jacobian (d y / d theta) by the implicit function theorem on the
closures: with J the pose Jacobian of the strut lengths (rows [u_k, (R b_k) x u_k] for
the platform twist dx = (dp, dw)),

    J dx = dl + u_k . da_k - (R^T u_k) . db_k,      dl_k = dz_k + q_k ds_k
    dy = R_T^T (dp - [R t]x dw - dp_T) + (d y / d phi) dphi

the last term (the frame's rotation vector) by central differences of Rodrigues'
formula (3 columns; the rest in closed form).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pkm_kinematics.errors import FieldError, KinematicsError
from pkm_kinematics.rotations import exp_so3, skew
from pkm_kinematics.struts import StrutMachine

__all__ = ["StrutErrorModel", "Prediction"]

FRAME_STEP = 1e-7       # rad: the frame rotation's central differences


@dataclass
class Prediction:
    """What the model predicts for a set of readings: the poses (p (N, 3), R (N, 3, 3))
    and the instrument's readings y (N, 3)."""

    position: np.ndarray
    rotation: np.ndarray
    y: np.ndarray


@dataclass(frozen=True)
class StrutErrorModel:
    """The parameters of a strut machine and an external instrument (module doc): a
    constant model; ``predict`` and ``jacobian`` take a parameter vector ``theta``."""

    machine: StrutMachine
    tool: tuple = (0.0, 0.0, 0.0)          # the point the instrument measures, platform frame (m)
    names: tuple = field(init=False)

    def __post_init__(self):
        n = self.machine.n_legs
        legs = self.machine.leg_names
        names = [f"{part}.{leg}.{c}" for part in ("a", "b") for leg in legs for c in "xyz"]
        names += [f"zero.{leg}" for leg in legs] + [f"scale.{leg}" for leg in legs]
        names += [f"frame.{c}" for c in ("x", "y", "z", "rx", "ry", "rz")]
        object.__setattr__(self, "names", tuple(names))
        if len(self.tool) != 3:
            raise FieldError("tool", f"expected the tool point (x, y, z) in the platform frame, got {self.tool!r}")
        assert len(names) == 8 * n + 6

    @property
    def size(self) -> int:
        return len(self.names)

    def split(self, theta) -> tuple:
        """(da (n, 3), db (n, 3), dz (n,), ds (n,), frame origin (3,), frame rotation vector (3,))."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.size,):
            raise FieldError("theta", f"expected {self.size} parameters ({', '.join(self.names[:3])}, ...), got "
                                      f"shape {theta.shape}")
        n = self.machine.n_legs
        return (theta[:3 * n].reshape(n, 3), theta[3 * n:6 * n].reshape(n, 3), theta[6 * n:7 * n],
                theta[7 * n:8 * n], theta[8 * n:8 * n + 3], theta[8 * n + 3:])

    def machine_for(self, theta) -> StrutMachine:
        """The machine with the geometry of ``theta`` (its limits and home the nominal ones)."""
        da, db, *_ = self.split(theta)
        m = self.machine
        return StrutMachine(m.name, m.leg_names, m.base_joints + da, m.platform_joints + db,
                            np.column_stack((m.joint_lower, m.joint_upper)), m.home, m.workspace,
                            characteristic_length_m=m.characteristic_length_m)

    def lengths(self, theta, readings) -> np.ndarray:
        """The struts' true lengths l = q + z + s q of encoder ``readings`` (N, n)."""
        _, _, dz, ds, _, _ = self.split(theta)
        q = np.asarray(readings, dtype=float)
        return q + dz + ds * q

    def predict(self, theta, readings, guesses=None) -> Prediction:
        """The poses the readings close to and what the instrument reads there.
        KinematicsError naming the reading whose forward kinematics fails."""
        readings = np.atleast_2d(np.asarray(readings, dtype=float))
        machine = self.machine_for(theta)
        lengths = self.lengths(theta, readings)
        *_, frame_p, frame_phi = self.split(theta)
        frame_r = exp_so3(frame_phi)
        tool = np.asarray(self.tool, dtype=float)
        ps, rs, ys = [], [], []
        for i, l_i in enumerate(lengths):
            guess = None if guesses is None else guesses[i]
            result = machine.forward_kinematics(l_i, guess=guess)
            if result.code.name != "CONVERGED":
                raise KinematicsError(f"reading {i}: forward kinematics {result.code.name.lower()} "
                                      f"(misfit {result.misfit_m:.3g} m)")
            ps.append(result.position)
            rs.append(result.rotation)
            ys.append(frame_r.T @ (result.position + result.rotation @ tool - frame_p))
        return Prediction(np.array(ps), np.array(rs), np.array(ys))

    def jacobian(self, theta, readings, prediction: Prediction | None = None) -> np.ndarray:
        """d y / d theta, (3 N, size): rows reading by reading (y's x, y, z), closed form
        but the frame rotation's 3 columns (module doc)."""
        readings = np.atleast_2d(np.asarray(readings, dtype=float))
        if prediction is None:
            prediction = self.predict(theta, readings)
        n = self.machine.n_legs
        da, db, dz, ds, frame_p, frame_phi = self.split(theta)
        base = self.machine.base_joints + da
        platform = self.machine.platform_joints + db
        frame_r = exp_so3(frame_phi)
        tool = np.asarray(self.tool, dtype=float)
        out = np.zeros((3 * len(readings), self.size))
        for i, (q, p, rot) in enumerate(zip(readings, prediction.position, prediction.rotation)):
            rb = platform @ rot.T                          # R b_k
            e = p + rb - base
            u = e / np.linalg.norm(e, axis=1, keepdims=True)
            jac = np.hstack((u, np.cross(rb, u)))           # d|e| = jac . (dp, dw)
            closure = np.zeros((n, self.size))              # J dx = closure dtheta
            for k in range(n):
                closure[k, 3 * k:3 * k + 3] = u[k]
                closure[k, 3 * n + 3 * k:3 * n + 3 * k + 3] = -(rot.T @ u[k])
                closure[k, 6 * n + k] = 1.0
                closure[k, 7 * n + k] = q[k]
            # (6, size): the pose's twist per parameter (more than six struts: the least-squares closure's)
            dx = np.linalg.solve(jac, closure) if n == 6 else np.linalg.lstsq(jac, closure, rcond=None)[0]
            point = rot @ tool
            dy_dx = frame_r.T @ np.hstack((np.eye(3), -skew(point)))
            rows = dy_dx @ dx
            rows[:, 8 * n:8 * n + 3] = -frame_r.T
            world = p + point - frame_p
            for c in range(3):                              # the frame's rotation vector
                h = np.zeros(3)
                h[c] = FRAME_STEP
                rows[:, 8 * n + 3 + c] = (exp_so3(frame_phi + h).T @ world
                                          - exp_so3(frame_phi - h).T @ world) / (2.0 * FRAME_STEP)
            out[3 * i:3 * i + 3] = rows
        return out
