"""A plant's scheduled loads in simulated time (pure, no rclpy): load entries, each
reached linearly from the one before over its ramp (a tool entering the material), as
the steps the plant applies.

An entry is (t_s, ramp_s, wrench): from t_s the load goes from the previous entry's
wrench (zero before the first) to ``wrench`` in round(ramp_s / dt_s) steps, one per
period (at least one: a ramp of 0 is a step at t_s). A scenario's ``load`` and
``frame_load`` (pkm_bringup.scenario) are such entries, and sim_hw's ``load_profile``
and ``frame_load_profile`` parameters carry them flat, so that a ramp is expanded
here, once, in the plant's process (a 0.2 s ramp at 1 kHz was 200 steps of numbers
through every run's parameter file).
"""

from __future__ import annotations

from pkm_kinematics.errors import FieldError

__all__ = ["profile_entries", "ramp_steps"]


def ramp_steps(entries, dt_s: float) -> list[tuple[float, tuple]]:
    """[(t_s, wrench)] steps of load entries [(t_s, ramp_s, wrench)] (module doc), the
    wrenches tuples of floats."""
    rows, previous = [], None
    for t, ramp, target in entries:
        target = tuple(target)
        if previous is None:
            previous = (0.0,) * len(target)
        steps = max(1, round(ramp / dt_s))
        for k in range(1, steps + 1):
            a = k / steps
            rows.append((t + (k - 1) * dt_s, tuple(p + a * (w - p) for p, w in zip(previous, target))))
        previous = target
    return rows


def profile_entries(flat, size: int, what: str) -> list[tuple[float, float, list]]:
    """The entries of a flat [t_s, ramp_s, w1 .. w<size>, ...] (sim_hw's load_profile), or
    FieldError naming ``what`` when it is not groups of size + 2 numbers or a ramp is
    outside [0, 10] s. (Times and wrenches are the schedule's to check: load_steps.)"""
    if len(flat) % (size + 2):
        raise FieldError(what, f"must hold groups of {size + 2} numbers [t_s, ramp_s, then {size} load "
                               f"components], got {len(flat)} numbers")
    entries = []
    for i in range(0, len(flat), size + 2):
        t, ramp, wrench = flat[i], flat[i + 1], list(flat[i + 2:i + 2 + size])
        if not 0.0 <= ramp <= 10.0:
            raise FieldError(what, f"ramp_s must be in [0, 10] s, got {ramp} at t_s = {t:g} s")
        entries.append((t, ramp, wrench))
    return entries
