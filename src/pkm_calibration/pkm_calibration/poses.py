"""Pose selection for a calibration and its program (pure).

The poses are chosen from candidates in the workspace to maximise the observability
index O1 of Borm & Menq ("Determination of optimal measurement configurations for
robot calibration based on observability measure", IJRR 10(1), 1991):

    O1 = (sigma_1 sigma_2 ... sigma_L)^(1/L) / sqrt(m)

the geometric mean of the singular values of the identification Jacobian (m rows, its
L identifiable columns scaled to unit norm over the candidates), i.e. the determinant of
the information matrix J^T J: greedy forward selection (each step adds the candidate
that multiplies det(J^T J) the most, det(M + B^T B) = det(M) det(I + B M^-1 B^T)), the
first steps regularised by a small multiple of the identity.

``calibration_program`` writes the poses as G-code in the machine's task words (mm and
degrees): a move to each pose and a dwell there, where the instrument is read.
"""

from __future__ import annotations

import math

import numpy as np

from pkm_kinematics.errors import FieldError

__all__ = ["workspace_bounds", "poses_clear", "route", "candidate_poses", "observability_index", "select_poses",
           "calibration_program"]

REGULARISATION = 1e-6       # times the identity in the information matrix while it is singular
ROUNDS = 20                 # draws of candidates before a workspace outside the strut limits is refused
BAR_ANGLE_DEG = 15.0        # a rail machine's candidates: every bar at least this far from its rail's
                            # direction and its normal (a pair of bars stretched along their rails cannot
                            # hold the platform across them; a bar across its rail, a carriage's
                            # motion is lost): the nominal model's forward kinematics closes there
                            # whatever the errors calibrated
MOVE_BAR_ANGLE_DEG = 10.0   # the same along the moves between them (the home pose may be near the first)


def observability_index(jacobian) -> float:
    """O1 of an identification Jacobian (module doc; its columns as given)."""
    jac = np.asarray(jacobian, dtype=float)
    s = np.linalg.svd(jac, compute_uv=False)
    if s[-1] <= 0.0:
        return 0.0
    return float(np.exp(np.mean(np.log(s))) / math.sqrt(jac.shape[0]))


def workspace_bounds(machine, angle_half_range_deg: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The task coordinates' bounds of a machine's workspace (a strut machine's box and
    rotation ranges, a planar machine's x, y and theta ranges); ``angle_half_range_deg``
    narrows the rotations to +-that (a planar machine: about the range's middle)."""
    ws = machine.workspace
    if "size" in ws and "center" in ws:          # a translating machine's cube
        center = np.asarray(ws["center"], dtype=float)
        return center - ws["size"] / 2, center + ws["size"] / 2
    if "center" in ws:
        half = np.radians(ws["abc_half_range_deg"])
        if angle_half_range_deg is not None:
            half = np.minimum(half, math.radians(angle_half_range_deg))
        return (np.concatenate((ws["center"] - ws["half_size"], -half)),
                np.concatenate((ws["center"] + ws["half_size"], half)))
    if machine.task_space.name != "planar":
        raise FieldError("machine", f"{machine.name}: calibration poses of strut and planar machines for now, not "
                                    f"{machine.task_space.name}")
    theta = np.radians(np.asarray(ws["theta_deg"], dtype=float))
    if angle_half_range_deg is not None:
        middle, half = theta.mean(), min(math.radians(angle_half_range_deg), (theta[1] - theta[0]) / 2)
        theta = np.array([middle - half, middle + half])
    return np.array([ws["x"][0], ws["y"][0], theta[0]]), np.array([ws["x"][1], ws["y"][1], theta[1]])


def poses_clear(machine, x, bar_angle_deg: float = BAR_ANGLE_DEG) -> np.ndarray:
    """Mask of poses (N, dof) a calibration may visit: reachable, within the joint
    limits, and on a rail machine every bar clear of its rail (BAR_ANGLE_DEG)."""
    x = np.atleast_2d(np.asarray(x, dtype=float))
    q, ok = machine.inverse_kinematics_batch(x)
    ok &= machine.within_joint_limits(np.where(np.isfinite(q), q, 0.0))
    if hasattr(machine, "rail_directions") and ok.any():         # a machine on rails
        ok[ok] &= _bars_clear_of_their_rails(machine, x[ok], q[ok], bar_angle_deg)
    return ok


def route(machine, start, poses, pool, samples: int = 25) -> tuple[np.ndarray, np.ndarray]:
    """The order the ``poses`` are visited from ``start`` (nearest first, distances
    scaled by the workspace's bounds) and the via points that keep every straight move
    clear (poses_clear on ``samples`` points of it): a move that is not gets the
    ``pool`` pose that makes both halves clear with the shortest detour. (waypoints,
    is_pose: False for a via point); FieldError when no pool pose does."""
    lo, hi = workspace_bounds(machine)
    scale = np.where(hi > lo, hi - lo, 1.0)
    s = np.linspace(0.0, 1.0, samples)[:, None]

    def clear(a, b) -> bool:
        return bool(poses_clear(machine, a + s * (b - a), MOVE_BAR_ANGLE_DEG).all())

    left = list(range(len(poses)))
    here = np.asarray(start, dtype=float)
    points, flags = [], []
    while left:
        k = min(left, key=lambda j: float(np.linalg.norm((poses[j] - here) / scale)))
        left.remove(k)
        target = poses[k]
        if not clear(here, target):
            detour = np.linalg.norm((pool - here) / scale, axis=1) + np.linalg.norm((pool - target) / scale, axis=1)
            for v in np.argsort(detour):
                if clear(here, pool[v]) and clear(pool[v], target):
                    points.append(pool[v])
                    flags.append(False)
                    break
            else:
                raise FieldError("poses", f"{machine.name}: no straight move nor via point reaches pose "
                                          f"{np.round(target, 4).tolist()} clear of the legs' limits")
        points.append(target)
        flags.append(True)
        here = target
    return np.array(points), np.array(flags)


def candidate_poses(machine, count: int, seed: int = 0, angle_half_range_deg: float | None = None) -> np.ndarray:
    """``count`` poses drawn uniformly in a machine's workspace (workspace_bounds), each
    within its joint limits."""
    rng = np.random.default_rng(seed)
    lo, hi = workspace_bounds(machine, angle_half_range_deg)
    out = []
    for _ in range(ROUNDS):
        x = rng.uniform(lo, hi, size=(count, len(lo)))
        out += list(x[poses_clear(machine, x)])
        if len(out) >= count:
            return np.array(out[:count])
    raise FieldError("workspace", f"{machine.name}: {len(out)} of {ROUNDS * count} poses drawn in the workspace "
                                  f"are within the joint limits; {count} candidates needed")


def _bars_clear_of_their_rails(machine, poses, q, bar_angle_deg: float) -> np.ndarray:
    """A rail machine's poses whose bars all make ``bar_angle_deg`` or more with their
    rail's direction and its normal."""
    bound = math.cos(math.radians(bar_angle_deg))
    ok = np.ones(len(poses), dtype=bool)
    for i, (x, qi) in enumerate(zip(poses, q)):
        base, joint = machine.leg_joints(x, qi)
        e = (joint - base)[:, :machine.rail_directions.shape[1]]
        c = np.abs(np.einsum("ij,ij->i", e, machine.rail_directions)) / np.linalg.norm(e, axis=1)
        ok[i] = bool(np.all(c <= bound) and np.all(c >= math.sin(math.radians(bar_angle_deg))))
    return ok


def select_poses(blocks: np.ndarray, count: int) -> list[int]:
    """The indices of ``count`` candidates whose Jacobian blocks (N, rows, L) give the
    largest det(J^T J) by greedy forward selection (module doc)."""
    blocks = np.asarray(blocks, dtype=float)
    n, rows, size = blocks.shape
    if not 0 < count <= n:
        raise FieldError("count", f"must be in [1, {n}] (the candidates), got {count}")
    if count * rows < size:
        raise FieldError("count", f"{count} poses give {count * rows} measurements for {size} parameters: "
                                  f"at least {math.ceil(size / rows)} poses")
    norms = np.sqrt(np.einsum("nrl,nrl->l", blocks, blocks))
    scaled = blocks / np.where(norms > 0.0, norms, 1.0)
    info = REGULARISATION * np.eye(size)
    chosen: list[int] = []
    free = np.ones(n, dtype=bool)
    for _ in range(count):
        inv = np.linalg.inv(info)
        gain = np.linalg.det(np.eye(rows) + np.einsum("nrl,lk,nsk->nrs", scaled, inv, scaled))
        gain[~free] = -np.inf
        k = int(np.argmax(gain))
        chosen.append(k)
        free[k] = False
        info += scaled[k].T @ scaled[k]
    return chosen


def calibration_program(space, poses, dwell_s: float = 0.5, feed_mm_min: float = 600.0,
                        comment: str = "", is_pose=None) -> str:
    """G-code visiting ``poses`` (task coordinates of ``space``, m and rad) with a dwell
    at each (the instrument is read there), in mm and degrees, absolute; ``is_pose``:
    False for a via point (route: passed without a dwell)."""
    if not dwell_s > 0.0 or not feed_mm_min > 0.0:
        raise FieldError("dwell_s", f"dwell and feed must be > 0, got {dwell_s} s, {feed_mm_min} mm/min")
    if "(" in comment or ")" in comment:
        raise FieldError("comment", f"no parentheses in a G-code comment, got {comment!r}")
    lines = ["%", f"(calibration program: {len(poses)} poses{': ' + comment if comment else ''})",
             "(each pose: a move, then a dwell while the encoders and the instrument are read)", "G21 G90 G94 G17 G61"]
    flags = [True] * len(poses) if is_pose is None else list(is_pose)
    k = 0
    for i, (x, dwell) in enumerate(zip(poses, flags)):
        words = []
        for word, value in zip(space.words, x):
            words.append(f"{word}{value * 1e3:.4f}" if word in "XYZ" else f"{word}{math.degrees(value):.5f}")
        feed = f" F{feed_mm_min:g}" if i == 0 else ""
        if dwell:
            k += 1
            lines += [f"N{k} G1 {' '.join(words)}{feed}", f"G4 P{dwell_s:g}"]
        else:
            lines.append(f"G1 {' '.join(words)}{feed} (via)")
    lines += ["M2", "%"]
    return "\n".join(lines) + "\n"
