"""The error model of a machine on rails (the bar model's rail case: ARCHI, MoM3's Delta,
the Orthoglide; MACHINE_MODEL.md), its encoders and, optionally, an instrument reading
one point of the tool (a laser tracker, or the Gough metrology's pose), in closed form
(pure).

Bar k (ARCHI §3.1): its carriage at A_k = a_k + across_k + (q_k + z_k) u_k on rail k,
its platform joint B_k = p + R (b_k + db_k), its length L_k + dL_k; the closure

    r_ik = |p_i + R_i (b_k + db_k) - a_k - across_k - (q_ik + z_k) u_k| - (L_k + dL_k) = 0

at every reading i, R_i the rotation about z of a planar machine's theta (a
translating machine: I). Parameters per leg: dL_k, the encoder's zero z_k, db_k (x, y
on a planar machine; x, y, z on a translating one, where a rail's shift across it is
the same as db_k's), and on a planar machine the rail's shift across it in the plane
(across_k = c_k n_k, n_k = z x u_k; along it, it is the zero). With an instrument, its
frame: it reads the tool point t (platform frame) as

    y_i = R_T^T (p_i + R_i t - p_T)      (its x, y on a planar machine)

frame (x, y, rz) on a planar machine, (x, y, z, rx, ry, rz: a rotation vector) on a
translating one. The unknowns are the parameters and every reading's pose; the
Jacobian in closed form, e = unit(B - A):

    dr/dp = e,  dr/dtheta = e . (z x R b'),  dr/ddL = -1,  dr/dz = -e . u,
    dr/ddb = e^T R,  dr/dc = -e . n,
    dy/dp = R_T^T,  dy/dtheta = R_T^T (z x R t),  dy/dp_T = -R_T^T

(the frame's rotation by central differences, FRAME_STEP). Identifiability: the
parameter columns with the poses' span projected out, reading by reading (the pose
Jacobian is block-diagonal), then QR with column pivoting (identify.identifiability).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from pkm_kinematics import bars as B
from pkm_kinematics.errors import FieldError
from pkm_kinematics.rotations import exp_so3

from .identify import Identifiability, identifiability

__all__ = ["RailErrorModel", "FRAME_STEP", "distance_pose_jacobian"]

FRAME_STEP = 1e-7       # rad: the instrument frame's rotation by central differences


def _rz(angle) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(np.shape(angle) + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1], out[..., 2, 2] = c, -s, s, c, 1.0
    return out


def distance_pose_jacobian(e, rb, planar: bool) -> np.ndarray:
    """d |p_i + R_i b_k - a_ik| / d (every pose) for the unit vectors e (N, k, 3) and
    R b (N, k, 3) (module doc: dr/dp = e, dr/dtheta = e . (z x R b)): (N, k, 3 N),
    block-diagonal; a planar pose is (x, y, theta), a translating one (x, y, z)."""
    N, k = e.shape[:2]
    d_pose = np.zeros((N, k, 3 * N))
    index = np.arange(N)
    for c in range(2 if planar else 3):
        d_pose[index, :, 3 * index + c] = e[:, :, c]
    if planar:
        d_pose[index, :, 3 * index + 2] = e[:, :, 1] * rb[:, :, 0] - e[:, :, 0] * rb[:, :, 1]
    return d_pose


@dataclass(frozen=True)
class RailErrorModel:
    """A machine on rails (rails.RailMachine: planar x, y, theta or translating x, y, z)
    and its error parameters, with an instrument on the tool point ``tool`` (platform
    frame, m) when ``instrument`` (module doc). Constant; the methods take the
    parameters ``theta``."""

    machine: object
    instrument: bool = False
    tool: tuple = (0.0, 0.0, 0.0)
    names: tuple = field(init=False)

    def __post_init__(self):
        m = self.machine
        if not hasattr(m, "rail_directions") or m.task_space.name not in ("planar", "position"):
            raise FieldError("machine", f"{m.name}: the rail error model is for machines on rails (planar or "
                                        f"translating), not {type(m).__name__} ({m.task_space.name})")
        per_leg = ("length", "zero", "b.x", "b.y", "rail.across") if self.planar else \
            ("length", "zero", "b.x", "b.y", "b.z")
        names = [f"{p}.{leg}" for leg in m.leg_names for p in per_leg]
        if self.instrument:
            names += self._instrument_names()
        if len(self.tool) != 3:
            raise FieldError("tool", f"expected the tool point (x, y, z) in the platform frame, got {self.tool!r}")
        object.__setattr__(self, "names", tuple(names))

    def _instrument_names(self) -> list[str]:
        """The instrument's parameters, after the legs': its frame (module doc)."""
        return [f"frame.{c}" for c in (("x", "y", "rz") if self.planar else ("x", "y", "z", "rx", "ry", "rz"))]

    @property
    def planar(self) -> bool:
        return self.machine.task_space.name == "planar"

    @property
    def size(self) -> int:
        return len(self.names)

    @property
    def readings_per_point(self) -> int:
        """What the instrument reads of a point: x, y on a planar machine, x, y, z otherwise."""
        return 2 if self.planar else 3

    def machine_for(self, theta):
        """The machine with the geometry of ``theta`` (rails.RailMachine.with_legs): each
        rail's origin moved by its zero along it and across it, each link's length and
        platform joint by theirs; a second path to the same bars (for tests and
        simulations)."""
        t = self._legs(theta)
        legs = []
        for k, leg in enumerate(self.machine.legs):
            dim = len(leg.rail_origin)
            u = np.asarray(leg.rail_direction, dtype=float)
            u = u / np.linalg.norm(u)
            origin = np.asarray(leg.rail_origin, dtype=float) + t[k, 1] * u
            if self.planar:
                origin = origin + t[k, 4] * np.array([-u[1], u[0]])
            point = np.asarray(leg.platform_point, dtype=float) + t[k, 2:2 + dim]
            legs.append(dataclasses.replace(leg, rail_origin=tuple(origin.tolist()), link_length=leg.link_length
                                            + t[k, 0], platform_point=tuple(point.tolist())))
        return self.machine.with_legs(self.machine.name + "_as_built", legs)

    def _legs(self, theta) -> np.ndarray:
        n = self.machine.n_legs
        return np.asarray(theta, dtype=float)[:5 * n].reshape(n, 5)

    def _frame(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """(p_T, R_T) of the instrument's frame."""
        f = np.asarray(theta, dtype=float)[5 * self.machine.n_legs:]
        if self.planar:
            return np.array([f[0], f[1], 0.0]), _rz(f[2])
        return f[:3].copy(), exp_so3(f[3:6])

    def _pose(self, poses) -> tuple[np.ndarray, np.ndarray]:
        """(p (N, 3), R (N, 3, 3)) of the task poses (N, 3)."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        if self.planar:
            return np.column_stack((poses[:, :2], np.zeros(len(poses)))), _rz(poses[:, 2])
        return poses.copy(), np.broadcast_to(np.eye(3), (len(poses), 3, 3))

    def _terms(self, theta, poses, readings):
        bars = self.machine.bars
        t = self._legs(theta)
        q = np.atleast_2d(np.asarray(readings, dtype=float))
        p, rot = self._pose(poses)
        a, u = bars[:, B.COL_A:B.COL_A + 3], bars[:, B.COL_U:B.COL_U + 3]
        normal = np.column_stack((-u[:, 1], u[:, 0], np.zeros(len(u))))     # z x u, in the plane
        b = bars[:, B.COL_B:B.COL_B + 3].copy()
        if self.planar:
            b[:, :2] += t[:, 2:4]
            a = a + t[:, 4:5] * normal
        else:
            b += t[:, 2:5]
        length = bars[:, B.COL_LENGTH] + t[:, 0]
        rb = np.einsum("nij,kj->nki", rot, b)                                # (N, n, 3): R b'
        carriage = a + (q + t[:, 1])[..., None] * u                           # (N, n, 3)
        e = p[:, None, :] + rb - carriage
        norm = np.linalg.norm(e, axis=-1)
        return norm - length, e / norm[..., None], rb, u, normal, rot

    def residuals(self, theta, poses, readings) -> np.ndarray:
        """r_ik (N, n) of the closures (module doc)."""
        return self._terms(theta, poses, readings)[0]

    def points(self, theta, poses) -> np.ndarray:
        """What the instrument reads at ``poses`` (N, 2 or 3)."""
        p, rot = self._pose(poses)
        frame_p, frame_r = self._frame(theta)
        world = p + rot @ np.asarray(self.tool, dtype=float)
        return ((world - frame_p) @ frame_r)[:, :self.readings_per_point]

    def jacobian(self, theta, poses, readings) -> tuple[np.ndarray, np.ndarray]:
        """The closures' (d r / d poses, d r / d theta): (N n, 3 N) block-diagonal in the
        poses, (N n, size)."""
        _, e, rb, u, normal, _ = self._terms(theta, poses, readings)
        N, n = e.shape[:2]
        d_pose = distance_pose_jacobian(e, rb, self.planar)
        d_theta = np.zeros((N, n, self.size))
        _, rot = self._pose(poses)
        er = np.einsum("nkj,nji->nki", e, rot)                               # e^T R (N, n, 3)
        for k in range(n):
            d_theta[:, k, 5 * k] = -1.0
            d_theta[:, k, 5 * k + 1] = -e[:, k] @ u[k]
            if self.planar:
                d_theta[:, k, 5 * k + 2:5 * k + 4] = er[:, k, :2]
                d_theta[:, k, 5 * k + 4] = -e[:, k] @ normal[k]
            else:
                d_theta[:, k, 5 * k + 2:5 * k + 5] = er[:, k]
        return d_pose.reshape(N * n, 3 * N), d_theta.reshape(N * n, self.size)

    def point_jacobian(self, theta, poses) -> tuple[np.ndarray, np.ndarray]:
        """The instrument's (d y / d poses, d y / d theta): (N d, 3 N), (N d, size)."""
        p, rot = self._pose(poses)
        N, d, n = len(p), self.readings_per_point, self.machine.n_legs
        frame_p, frame_r = self._frame(theta)
        rt = rot @ np.asarray(self.tool, dtype=float)                          # (N, 3)
        d_pose = np.zeros((N, d, 3 * N))
        d_theta = np.zeros((N, d, self.size))
        index = np.arange(N)
        back = frame_r.T[:d]                                                   # (d, 3)
        if self.planar:
            for c in range(2):
                d_pose[index, :, 3 * index + c] = back[:, c]
            d_pose[index, :, 3 * index + 2] = (np.column_stack((-rt[:, 1], rt[:, 0], np.zeros(N))) @ back.T)
            d_theta[:, :, 5 * n:5 * n + 2] = -back[:, :2]
            rotations = [5 * n + 2]
        else:
            for c in range(3):
                d_pose[index, :, 3 * index + c] = back[:, c]
            d_theta[:, :, 5 * n:5 * n + 3] = -back
            rotations = [5 * n + 3, 5 * n + 4, 5 * n + 5]
        for col in rotations:                                                  # the frame's rotation
            h = np.zeros(self.size)
            h[col] = FRAME_STEP
            d_theta[:, :, col] = (self.points(theta + h, poses) - self.points(theta - h, poses)) / (2 * FRAME_STEP)
        return d_pose.reshape(N * d, 3 * N), d_theta.reshape(N * d, self.size)

    def pose_blocks(self, poses, readings, scales=(1.0, 1.0)) -> np.ndarray:
        """Each reading's rows (closures over ``scales[0]``, the instrument's over
        ``scales[1]``) of d / d theta at nominal with its pose's span projected out
        (N, rows, size): what a change of the parameters does at that reading that no
        change of its pose explains (module doc)."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        N, n = len(poses), self.machine.n_legs
        zero = np.zeros(self.size)
        d_pose, d_theta = self.jacobian(zero, poses, readings)
        pose = np.stack([d_pose[i * n:(i + 1) * n, 3 * i:3 * i + 3] for i in range(N)]) / scales[0]
        blocks = d_theta.reshape(N, n, self.size) / scales[0]
        if self.instrument:
            d = self.readings_per_point
            y_pose, y_theta = self.point_jacobian(zero, poses)
            pose = np.concatenate((pose, np.stack([y_pose[i * d:(i + 1) * d, 3 * i:3 * i + 3]
                                                   for i in range(N)]) / scales[1]), axis=1)
            blocks = np.concatenate((blocks, y_theta.reshape(N, d, self.size) / scales[1]), axis=1)
        basis, _ = np.linalg.qr(pose)
        return blocks - basis @ np.einsum("nkj,nkl->njl", basis, blocks)

    def parameter_jacobian(self, poses, readings, scales=(1.0, 1.0)) -> np.ndarray:
        """pose_blocks, stacked."""
        return self.pose_blocks(poses, readings, scales).reshape(-1, self.size)

    def identifiability(self, poses, readings, scales=(1.0, 1.0)) -> Identifiability:
        """What the readings at ``poses`` identify."""
        return identifiability(self.parameter_jacobian(poses, readings, scales), self.names)
