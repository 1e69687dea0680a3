"""Compensation tables from a calibration run (pure): what the identified geometry
leaves along each drive (pkm_kinematics.compensation).

Where the instrument fixes the pose (a translating machine whose tool point it reads:
MoM3 with its Gough), every dwell gives each drive's true position, q*_k = IK_theta(x)
of the identified machine at the measured pose, against its reading q_k; the table
c_k(q) is the piecewise-linear function, knots every ``spacing_m`` over the readings'
range, that fits q*_k - q_k by least squares (hat-function basis, a small ridge for
knots with few readings), its mean removed (the geometry's zero holds it).
"""

from __future__ import annotations

import numpy as np

from pkm_kinematics.compensation import MAX_POINTS, Compensation, DriveTable
from pkm_kinematics.errors import FieldError

__all__ = ["true_drive_positions", "fit_table", "fit_tables"]

RIDGE = 1e-6          # times the normal matrix's mean diagonal: knots no reading reaches stay near their neighbours


def true_drive_positions(model, theta, points) -> np.ndarray:
    """q* (N, n) of a translating rail machine (rail_errors.RailErrorModel with an
    instrument, its frame at nominal) at the poses its instrument's ``points`` (N, 3) say."""
    if model.planar or not model.instrument:
        raise FieldError("machine", "drive tables need the pose from the instrument alone: a translating machine "
                                    "whose tool point it reads (MoM3 and its Gough)")
    poses = np.asarray(points, dtype=float)[:, :3] - np.asarray(model.tool, dtype=float)
    q, ok = model.machine_for(theta).inverse_kinematics_batch(poses)
    if not ok.all():
        raise FieldError("points", f"{int((~ok).sum())} measured poses are out of the identified machine's reach")
    return q


def _hats(q, knots) -> np.ndarray:
    """(N, K): the piecewise-linear basis at ``q``."""
    out = np.zeros((len(q), len(knots)))
    k = np.clip(np.searchsorted(knots, q) - 1, 0, len(knots) - 2)
    w = np.clip((q - knots[k]) / (knots[k + 1] - knots[k]), 0.0, 1.0)
    out[np.arange(len(q)), k] = 1.0 - w
    out[np.arange(len(q)), k + 1] = w
    return out


def fit_table(readings, errors, spacing_m: float) -> DriveTable:
    """One drive's table: knots every ``spacing_m`` over its ``readings``' range fitted
    to ``errors`` (q* - q) (module doc)."""
    q, e = np.asarray(readings, dtype=float), np.asarray(errors, dtype=float)
    if not spacing_m > 0.0:
        raise FieldError("spacing_m", f"must be > 0 m, got {spacing_m}")
    count = int(np.ceil((q.max() - q.min()) / spacing_m)) + 1
    if not 2 <= count <= MAX_POINTS:
        raise FieldError("spacing_m", f"{count} knots over {q.max() - q.min():.4g} m: 2 to {MAX_POINTS}")
    knots = q.min() + spacing_m * np.arange(count)
    basis = _hats(q, knots)
    normal = basis.T @ basis
    values = np.linalg.solve(normal + RIDGE * np.trace(normal) / count * np.eye(count), basis.T @ e)
    return DriveTable(knots, values - values.mean())


def fit_tables(readings, true_positions, spacing_m: float) -> tuple[Compensation, np.ndarray, np.ndarray]:
    """(the tables of every drive, the RMS of q* - q about its mean per drive before, and
    after the tables)."""
    q, qs = np.asarray(readings, dtype=float), np.asarray(true_positions, dtype=float)
    errors = qs - q
    tables = tuple(fit_table(q[:, k], errors[:, k] - errors[:, k].mean(), spacing_m) for k in range(q.shape[1]))
    comp = Compensation(tables)
    after = qs - np.array([comp.positions(row) for row in q])
    spread = lambda e: np.sqrt(np.mean((e - e.mean(axis=0)) ** 2, axis=0))     # noqa: E731 (the zero takes the mean)
    return comp, spread(errors), spread(after)
