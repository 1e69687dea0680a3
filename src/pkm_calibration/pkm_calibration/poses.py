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

__all__ = ["candidate_poses", "observability_index", "select_poses", "calibration_program"]

REGULARISATION = 1e-6       # times the identity in the information matrix while it is singular
ROUNDS = 20                 # draws of candidates before a workspace outside the strut limits is refused


def observability_index(jacobian) -> float:
    """O1 of an identification Jacobian (module doc; its columns as given)."""
    jac = np.asarray(jacobian, dtype=float)
    s = np.linalg.svd(jac, compute_uv=False)
    if s[-1] <= 0.0:
        return 0.0
    return float(np.exp(np.mean(np.log(s))) / math.sqrt(jac.shape[0]))


def candidate_poses(machine, count: int, seed: int = 0) -> np.ndarray:
    """``count`` poses drawn uniformly in a strut machine's workspace box and rotation
    ranges, each within its strut limits."""
    rng = np.random.default_rng(seed)
    ws = machine.workspace
    lo = np.concatenate((ws["center"] - ws["half_size"], -np.radians(ws["abc_half_range_deg"])))
    hi = np.concatenate((ws["center"] + ws["half_size"], np.radians(ws["abc_half_range_deg"])))
    out = []
    for _ in range(ROUNDS):
        x = rng.uniform(lo, hi, size=(count, 6))
        q, ok = machine.inverse_kinematics_batch(x)
        out += list(x[ok & machine.within_joint_limits(np.where(np.isfinite(q), q, 0.0))])
        if len(out) >= count:
            return np.array(out[:count])
    raise FieldError("workspace", f"{machine.name}: {len(out)} of {ROUNDS * count} poses drawn in the workspace "
                                  f"are within the strut limits; {count} candidates needed")


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
                        comment: str = "") -> str:
    """G-code visiting ``poses`` (task coordinates of ``space``, m and rad) with a dwell
    at each (the instrument is read there), in mm and degrees, absolute."""
    if not dwell_s > 0.0 or not feed_mm_min > 0.0:
        raise FieldError("dwell_s", f"dwell and feed must be > 0, got {dwell_s} s, {feed_mm_min} mm/min")
    lines = ["%", f"(calibration program: {len(poses)} poses{': ' + comment if comment else ''})",
             "(each pose: a move, then a dwell while the instrument reads)", "G21 G90 G94 G17 G61"]
    for k, x in enumerate(poses, start=1):
        words = []
        for word, value in zip(space.words, x):
            words.append(f"{word}{value * 1e3:.4f}" if word in "XYZ" else f"{word}{math.degrees(value):.5f}")
        lines.append(f"N{k} G1 {' '.join(words)}" + (f" F{feed_mm_min:g}" if k == 1 else ""))
        lines.append(f"G4 P{dwell_s:g}")
    lines += ["M2", "%"]
    return "\n".join(lines) + "\n"
