"""Timing figures the nodes write into their JSON summaries (no rclpy)."""

from __future__ import annotations

import math

import numpy as np


def percentiles_us(name: str, samples_s) -> dict:
    """{"<name>_us_p50": ..., "<name>_us_p99": ...} of durations given in seconds;
    NaN when there are none (a run that never cycled)."""
    us = np.asarray(samples_s if len(samples_s) else [math.nan], dtype=float) * 1e6
    return {f"{name}_us_p50": float(np.percentile(us, 50)), f"{name}_us_p99": float(np.percentile(us, 99))}
