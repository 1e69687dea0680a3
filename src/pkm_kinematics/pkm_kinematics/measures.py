"""Measures of a Jacobian that every machine model uses (written once)."""

from __future__ import annotations

import numpy as np


def condition_numbers(jacobians: np.ndarray) -> np.ndarray:
    """2-norm condition numbers of a stack of Jacobians (N, n, m): NaN for rows with NaN
    (unreachable), inf for singular rows and for rows with infinite entries (a leg
    perpendicular to its rail makes J_m unbounded)."""
    out = np.full(jacobians.shape[0], np.nan)
    ok = np.isfinite(jacobians).all(axis=(1, 2))
    out[~ok & ~np.isnan(jacobians).any(axis=(1, 2))] = np.inf
    if ok.any():
        s = np.linalg.svd(jacobians[ok], compute_uv=False)
        with np.errstate(divide="ignore", invalid="ignore"):
            out[ok] = np.where(s[:, -1] > 0.0, s[:, 0] / s[:, -1], np.inf)
    return out


def cube_grid(center, size: float, points_per_axis: int) -> np.ndarray:
    """A regular grid over a cube of edge ``size`` about ``center``: (N, 3) points."""
    half = size / 2.0
    axes = [np.linspace(c - half, c + half, points_per_axis) for c in center]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


__all__ = ["condition_numbers", "cube_grid"]
