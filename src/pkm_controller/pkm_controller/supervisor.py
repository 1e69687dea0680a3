"""The controller's safety supervisor (pure core, no rclpy): every check of a cycle
returns a :class:`Trip` (what stops the machine, and its ``TripCause``) or None.

It checks the inputs (NaN, lengths; the metrology the strategy needs), the forces
the drives report against the commands (a failed drive: dropped when the machine
can go on without it, ARCHI §2), the limits codes of the compiled kernels (joint,
workspace, singularity margin, following error: ``laws.limits_kernel``) and the
saturation of the commands. It keeps the stop: the first trip's reason and cause
are the ones reported, whatever follows.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pkm_common.causes import TripCause

from .laws import CycleCode
from .strategies import Feedback

__all__ = ["Supervisor", "Trip"]


class Trip(NamedTuple):
    """What stops the machine: the message reported and its cause."""
    reason: str
    cause: TripCause


class Supervisor:
    """The checks of one controller and the stop they lead to. ``names``: the drives;
    ``dof``: the task's; ``joint_box`` / ``workspace_box``: (lower, upper) per drive
    and per task axis (laws.limits_kernel); ``space``: the task space
    (pkm_kinematics.task_space); ``condition``: cond(J_m) of a set of drive rows."""

    def __init__(self, config, names: list, dof: int, space, joint_box, workspace_box, condition, model):
        self.config = config
        self.names, self.n, self.dof, self.space = names, len(names), dof, space
        self.joint_box, self.workspace_box = joint_box, workspace_box
        self.condition, self.model = condition, model
        self.reset()

    def reset(self) -> None:
        self.stopped = False
        self.stop_reason = ""
        self.stop_cause = TripCause.NONE
        self.faults: list[str] = []
        self.active = list(range(self.n))          # the drives that take part
        self.failed: dict[int, str] = {}           # drive -> what it stopped doing
        self.mismatch = [0] * self.n               # consecutive cycles off its command, per drive
        self.forces_mismatched = False             # a drive's reported force differs from its command, this
                                                   # cycle (reset by the caller before check_drives)
        self.saturated_since = None
        self.saturation_count = 0

    # ------------------------------------------------------------------ the stop
    def trip(self, reason: str, cause: TripCause) -> None:
        """Stop; the first reason and cause are kept and reported."""
        if not self.stopped:
            self.stopped, self.stop_reason, self.stop_cause = True, reason, TripCause(cause)
            self.faults.append(reason)

    # ---------------------------------------------------------------- the checks
    def check_state(self, q, qdot, applied) -> Trip | None:
        """A drive state's lengths and values."""
        for name, values, size in (("position", q, self.n), ("velocity", qdot, self.n)):
            if len(values) != size:
                return Trip(f"drives/state: {name} has {len(values)} values, expected {size} ({self.names})",
                            TripCause.INPUT_REFUSED)
            if not math.isfinite(sum(values)):
                k = next((i for i, v in enumerate(values) if not math.isfinite(v)), None)
                if k is None:             # each finite, their sum not: the largest is named
                    k = max(range(size), key=lambda i: abs(values[i]))
                return Trip(f"drives/state: {name}[{k}] ({self.names[k]}) is {values[k]}", TripCause.INPUT_REFUSED)
        if applied is not None and len(applied) and (len(applied) != self.n or not math.isfinite(sum(applied))):
            return Trip(f"drives/state: effort must be {self.n} finite values, got {list(applied)}",
                        TripCause.INPUT_REFUSED)
        return None

    def check_metrology(self, feedback: Feedback, struts, metrology_pose) -> Trip | None:
        """The metrology reading the strategy feeds back (``feedback``)."""
        if feedback == Feedback.STRUTS:
            if struts is None or len(struts) != 6 or not math.isfinite(sum(struts)):
                return Trip(f"metrology/struts: expected 6 finite strut lengths, got {struts}",
                            TripCause.INPUT_REFUSED)
        if feedback == Feedback.GOUGH_POSE:
            if metrology_pose is None:
                return Trip("metrology/pose: missing (the DKM did not converge or the sensor is silent)",
                            TripCause.INPUT_REFUSED)
            p, r = metrology_pose
            if len(p) != 3 or not math.isfinite(sum(p)) or not np.isfinite(r).all():
                return Trip(f"metrology/pose: not a finite pose ({p})", TripCause.INPUT_REFUSED)
        return None

    def check_drives(self, applied, commanded, pose) -> Trip | None:
        """Compare the forces the drives report with what was ``commanded`` for this
        period; a drive off by more than drive_mismatch_n for drive_mismatch_cycles
        cycles has failed. No force: it is dropped (if allowed and the remaining
        sub-machine at ``pose`` is well conditioned); any other mismatch (a brake, a
        jam): a trip."""
        c = self.config
        for i in self.active:
            if abs(applied[i] - commanded[i]) > c.drive_mismatch_n:
                self.mismatch[i] += 1
                self.forces_mismatched = True
            else:
                self.mismatch[i] = 0
            if self.mismatch[i] < c.drive_mismatch_cycles:
                continue
            kind = "no force" if abs(applied[i]) < c.drive_mismatch_n else \
                f"reports {applied[i]:.1f} N for {commanded[i]:.1f} N commanded"
            what = f"drive {self.names[i]} failed ({kind})"
            remaining = [k for k in self.active if k != i]
            if kind != "no force" or not c.continue_on_drive_failure or len(remaining) < self.dof:
                return Trip(what, TripCause.DRIVE_FAILURE)
            rows = self.model.velocity_terms(pose, (0.0,) * self.dof)[1]
            cond = self.condition([rows[k] for k in remaining])
            name = "J_" + "".join(str(k + 1) for k in remaining)
            if cond > c.max_condition:
                return Trip(f"{what}; sub-machine {name} too close to singular (condition {cond:.3g} > "
                            f"{c.max_condition:g})", TripCause.DRIVE_FAILURE)
            self.active = remaining
            self.failed[i] = kind
            self.faults.append(f"{what}: continuing on {name} (condition {cond:.3g})")
        return None

    def drives_agree(self) -> None:
        """``check_drives`` of a cycle in which every drive applied its command (a
        compiled caller found it): no mismatch counts."""
        if any(self.mismatch):
            self.mismatch = [0] * self.n

    def limit_trip(self, code: int, index: int, value: float) -> Trip:
        """The trip of a limits code (laws.CycleCode, not OK) of the limits kernels."""
        c = self.config
        if code == CycleCode.JOINT_LIMIT:
            lo, hi = self.joint_box[index].tolist()
            return Trip(f"joint limit: drive {self.names[index]} at {value:.6g} m outside [{lo:g}, {hi:g}] m",
                        TripCause.JOINT_LIMIT)
        if code == CycleCode.WORKSPACE_LIMIT:
            lo, hi = self.workspace_box[index].tolist()
            unit, margin = ("m", "workspace_margin_m") if index < self.space.translation_axes else \
                ("rad", "workspace_margin_rad")
            return Trip(f"workspace: {self.space.axes[index]} = {value:.6g} {unit} outside [{lo:.6g}, {hi:.6g}] "
                        f"{unit} ({margin} {getattr(c, margin):g})", TripCause.WORKSPACE)
        if code == CycleCode.SINGULARITY_MARGIN:
            return Trip(f"singularity margin: condition number {value:.6g} > max_condition {c.max_condition:g}",
                        TripCause.SINGULARITY)
        if code == CycleCode.FOLLOWING_ERROR_M:
            return Trip(f"following error {value * 1e3:.3f} mm > following_error_m {c.following_error_m:g}",
                        TripCause.FOLLOWING_ERROR)
        if code == CycleCode.FOLLOWING_ERROR_RAD:
            return Trip(f"following error {value:.4f} rad > following_error_rad {c.following_error_rad:g}",
                        TripCause.FOLLOWING_ERROR)
        return Trip(f"{c.strategy}: unknown supervisor code {code} (index {index}, value {value:g})",
                    TripCause.KINEMATICS)

    def check_saturation(self, t_s: float, saturated: int) -> Trip | None:
        """Commands clamped at force_limit_n without a break for saturation_trip_s."""
        c = self.config
        if not saturated:
            self.saturated_since = None
            return None
        self.saturation_count += 1
        self.saturated_since = t_s if self.saturated_since is None else self.saturated_since
        if c.saturation_trip_s and t_s - self.saturated_since >= c.saturation_trip_s - 1e-9:
            return Trip(f"drive forces saturated at {c.force_limit_n:g} N for {c.saturation_trip_s:g} s",
                        TripCause.SATURATION)
        return None

