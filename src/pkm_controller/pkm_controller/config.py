"""The controller's configuration (config/controller/*.yaml), like ros2_controllers'
parameter files: every parameter with its unit and default, the choices it names,
and the checks that need no machine (:meth:`ControllerConfig.validate`; what only a
machine can say is :mod:`pkm_controller.tuning`'s). Pure, no rclpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from pkm_kinematics.distribution import METHODS, TWO_ARM
from pkm_kinematics.errors import FieldError

from .reference import PEAK_RATE, approach_duration
from .strategies import NAMES

STRATEGIES = NAMES          # the registry's names (pkm_controller.strategies), in its order
# how the encoder pose is found: solved every cycle (Newton, warm-started), or carried by
# the drive increments (Sliding Star §3.1, pkm_kinematics.online_fk), by the midpoint
# rule or by explicit Euler: name -> integration order (0: solved)
FORWARD_KINEMATICS = {"newton": 0, "integrated": 2, "integrated_euler": 1}
SENSOR_JACOBIAN_POSES = ("estimated", "desired")
# the farthest a trajectory may start from the reference and still be approached
# (tracking.Approach): a correction of the machine's own position, not a move
MAX_APPROACH_M, MAX_APPROACH_RAD, MAX_APPROACH_S = 0.1, 0.5, 60.0
# what an operator may change in a running controller (ControllerCore.change_settings)
RUNTIME_SETTINGS = ("strategy", "distribution", "p_norm", "prestress_n", "bandwidth_hz", "damping_ratio",
                    "integral_time_s")


@dataclass
class ControllerConfig:
    """Controller parameters (config/controller/*.yaml). SI units."""

    strategy: str = "computed_torque"
    distribution: str = "pseudo_inverse"
    p_norm: float = 4.0                   # p of the p_norm distribution
    prestress_n: float = 0.0              # internal force added along ker(J^T) (redundant machines)
    prestress_direction: tuple = ()       # n drive forces: the pattern of that internal force where ker(J^T)
                                          # has more than one dimension (projected on it; a redundant hexapod)
    bandwidth_hz: float = 20.0            # closed-loop bandwidth omega / 2 pi
    damping_ratio: float = 1.0
    integral_time_s: float = 0.05         # T_i; 0 disables the integral action (and its holding start)
    dt_s: float = 0.001                   # nominal period (the first cycle; then the stamps)
    force_limit_n: float = 2000.0         # commands are clamped here (saturation counted)
    saturation_trip_s: float = 0.5        # continuous saturation for this long trips (0: never)
    following_error_m: float = 0.01       # |x_d - x| translation that trips
    following_error_rad: float = 0.05     # rotation error that trips (planar, spatial)
    max_condition: float = 100.0          # singularity margin: cond(J of the active drives)
    workspace_margin_m: float = 0.02      # the measured pose may leave the workspace box by this much
    workspace_margin_rad: float = 0.02    # ... and a spatial machine's a, b, c their ranges by this much
    start_tolerance_m: float = 0.005      # a trajectory must start this close to the current reference
    start_tolerance_rad: float = 0.04     # (each below its following-error bound: the reference jumps by it)
    start_approach_m: float = 0.0         # farther, but within this: a move to the trajectory's start first (0: off)
    start_approach_rad: float = 0.0       # ... and within this rotation (3-DOF machines; tracking.Approach)
    approach_speed_m_s: float = 0.02      # the approach move's peak speed
    approach_speed_rad_s: float = 0.1     # ... and peak rotation rate
    approach_acceleration_m_s2: float = 0.2     # ... its peak acceleration
    approach_acceleration_rad_s2: float = 1.0   # ... and angular acceleration
    approach_duration_s: float = 0.0      # 0: from those; else every trajectory starts with an approach this long
                                          # (a hold where it starts at the reference): the same timing every run
    drive_mismatch_n: float = 50.0        # |reported - commanded force| that counts as a mismatch
    drive_mismatch_cycles: int = 5        # consecutive mismatches that declare a drive failed
    actuation_delay_cycles: int = 0       # the drives apply a command this many cycles after the next state
                                          # (CiA 402 drives with synchronous RPDOs: 1); the drive supervision
                                          # compares their forces with the command they applied
    continue_on_drive_failure: bool = True
    encoder_jump_m: float = 2e-5          # a reading off its expected motion by this much in one cycle (0: off)
    encoder_freeze_m: float = 2e-4        # a reading held while the reference moved its drive this much (0: off)
    encoder_gough_m: float = 1e-4         # metrology strategies: a reading this far off the Gough's (0: off)
    forward_kinematics: str = "newton"    # the encoder pose: newton | integrated | integrated_euler (§3.1)
    fk_resync_cycles: int = 0             # integrated: a Newton solution every N cycles (0: never)
    sensor_jacobian: str = "estimated"    # sensor_space: J_t at the estimated real pose, or the desired (MoM3 §6.4)

    def validate(self, n_drives: int, planar: bool) -> None:
        checks = [
            ("strategy", self.strategy in NAMES, f"one of {list(NAMES)}"),
            ("distribution", self.distribution in METHODS, f"one of {list(METHODS)}"),
            ("distribution", self.distribution not in TWO_ARM or (planar and n_drives == 4),
             f"{self.distribution} only on a planar machine of two leg pairs (4 drives)"),
            ("p_norm", 2.0 <= self.p_norm <= 64.0, "in [2, 64]"),
            ("prestress_direction", len(self.prestress_direction) in (0, n_drives) and all(
                math.isfinite(v) for v in self.prestress_direction) and (
                not self.prestress_direction or any(self.prestress_direction)),
             f"empty, or {n_drives} finite drive forces, not all zero"),
            ("prestress_n", math.isfinite(self.prestress_n) and (
                self.prestress_n == 0.0 or n_drives == 4 or len(self.prestress_direction) == n_drives),
             "0, or finite on a machine with one redundant drive (4 drives) or with a prestress_direction"),
            # beyond the drives' limit the internal force alone saturates them
            ("prestress_n", not self.force_limit_n > 0.0 or abs(self.prestress_n) <= self.force_limit_n,
             f"in [-{self.force_limit_n:g}, {self.force_limit_n:g}] N (force_limit_n)"),
            ("bandwidth_hz", 0.0 < self.bandwidth_hz <= 0.1 / self.dt_s if self.dt_s > 0 else False,
             f"in (0, {0.1 / self.dt_s if self.dt_s > 0 else 0:g}] Hz (a tenth of the control rate)"),
            ("damping_ratio", 0.1 <= self.damping_ratio <= 10.0, "in [0.1, 10]"),
            ("dt_s", 0.0 < self.dt_s <= 0.1, "in (0, 0.1] s"),
            ("force_limit_n", 0.0 < self.force_limit_n < math.inf, "in (0, inf) N"),
            ("saturation_trip_s", 0.0 <= self.saturation_trip_s < math.inf, "in [0, inf) s"),
            ("following_error_m", 0.0 < self.following_error_m < math.inf, "in (0, inf) m"),
            ("following_error_rad", 0.0 < self.following_error_rad < math.inf, "in (0, inf) rad"),
            ("max_condition", 1.0 <= self.max_condition < math.inf, "in [1, inf)"),
            ("workspace_margin_m", 0.0 <= self.workspace_margin_m < math.inf, "in [0, inf) m"),
            ("workspace_margin_rad", 0.0 <= self.workspace_margin_rad < math.inf, "in [0, inf) rad"),
            # a trajectory accepted this far from the reference starts with a jump of that much
            ("start_tolerance_m", 0.0 <= self.start_tolerance_m < self.following_error_m,
             f"in [0, {self.following_error_m:g}) m (below following_error_m)"),
            ("start_tolerance_rad", 0.0 <= self.start_tolerance_rad < self.following_error_rad,
             f"in [0, {self.following_error_rad:g}) rad (below following_error_rad)"),
            ("start_approach_m", self.start_approach_m == 0.0
             or self.start_tolerance_m <= self.start_approach_m <= MAX_APPROACH_M,
             f"0 (off), or in [{self.start_tolerance_m:g}, {MAX_APPROACH_M:g}] m (from start_tolerance_m)"),
            ("start_approach_rad", self.start_approach_rad == 0.0
             or self.start_tolerance_rad <= self.start_approach_rad <= MAX_APPROACH_RAD,
             f"0 (off), or in [{self.start_tolerance_rad:g}, {MAX_APPROACH_RAD:g}] rad (from start_tolerance_rad)"),
            ("approach_speed_m_s", 1e-3 <= self.approach_speed_m_s <= 1.0
             and PEAK_RATE * self.start_approach_m <= MAX_APPROACH_S * self.approach_speed_m_s,
             f"in [0.001, 1] m/s, and start_approach_m ({self.start_approach_m:g} m) within {MAX_APPROACH_S:g} s"),
            ("approach_speed_rad_s", 1e-3 <= self.approach_speed_rad_s <= 2.0
             and PEAK_RATE * self.start_approach_rad <= MAX_APPROACH_S * self.approach_speed_rad_s,
             f"in [0.001, 2] rad/s, and start_approach_rad ({self.start_approach_rad:g} rad) within "
             f"{MAX_APPROACH_S:g} s"),
            ("approach_acceleration_m_s2", 1e-3 <= self.approach_acceleration_m_s2 <= 10.0, "in [0.001, 10] m/s^2"),
            ("approach_acceleration_rad_s2", 1e-3 <= self.approach_acceleration_rad_s2 <= 50.0,
             "in [0.001, 50] rad/s^2"),
            ("approach_duration_s", self.approach_duration_s == 0.0
             or self.start_approach_m > 0.0 or self.start_approach_rad > 0.0,
             "0 without an approach (start_approach_m and start_approach_rad 0)"),
            ("approach_duration_s", self.approach_duration_s == 0.0
             or self.approach_fastest_s() <= self.approach_duration_s <= MAX_APPROACH_S,
             f"0 (from the speeds), or in [{self.approach_fastest_s():.4g}, {MAX_APPROACH_S:g}] s (the longest "
             f"approach, start_approach_m and _rad, within approach_speed_* and approach_acceleration_*)"),
            ("drive_mismatch_n", 0.0 < self.drive_mismatch_n < math.inf, "in (0, inf) N"),
            ("drive_mismatch_cycles", 1 <= self.drive_mismatch_cycles <= 10000, "in [1, 10000]"),
            ("actuation_delay_cycles", 0 <= self.actuation_delay_cycles <= 8, "in [0, 8]"),
            ("encoder_jump_m", 0.0 <= self.encoder_jump_m < math.inf, "in [0, inf) m (0: off)"),
            ("encoder_freeze_m", 0.0 <= self.encoder_freeze_m < math.inf, "in [0, inf) m (0: off)"),
            ("encoder_gough_m", 0.0 <= self.encoder_gough_m < math.inf, "in [0, inf) m (0: off)"),
            ("forward_kinematics", self.forward_kinematics in FORWARD_KINEMATICS, f"one of {list(FORWARD_KINEMATICS)}"),
            ("sensor_jacobian", self.sensor_jacobian in SENSOR_JACOBIAN_POSES, f"one of {list(SENSOR_JACOBIAN_POSES)}"),
            ("fk_resync_cycles", 0 <= self.fk_resync_cycles <= 10**9, "in [0, 1e9] (0: never)"),
        ]
        if self.integral_time_s != 0.0:
            omega = 2.0 * math.pi * self.bandwidth_hz
            low = 1.0 / (2.0 * self.damping_ratio * omega) if omega > 0 else 0.0
            checks.append(("integral_time_s", low < self.integral_time_s < math.inf,
                           f"0, or in ({low:.4g}, inf) s (stability: T_i > 1 / (2 zeta omega))"))
        for name, ok, allowed in checks:
            if not ok:
                raise FieldError.out_of_range(name, allowed, getattr(self, name))

    def approach_fastest_s(self) -> float:
        """The shortest duration of the longest approach move (start_approach_m and
        start_approach_rad) within the approach's speeds and accelerations (inf where one
        of those is out of its range: refused by its own check)."""
        bounds = (self.approach_speed_m_s, self.approach_speed_rad_s, self.approach_acceleration_m_s2,
                  self.approach_acceleration_rad_s2)
        if not all(b > 0.0 and math.isfinite(b) for b in bounds):
            return math.inf
        return approach_duration(self.start_approach_m, self.start_approach_rad, self.approach_speed_m_s,
                                 self.approach_speed_rad_s, self.approach_acceleration_m_s2,
                                 self.approach_acceleration_rad_s2)

    def with_changes(self, changes: dict) -> "ControllerConfig":
        """This configuration with ``changes`` of ``RUNTIME_SETTINGS`` (numbers as floats);
        ValueError naming the field for a name that is not a runtime setting or a value
        of the wrong kind. The ranges are checked by whoever applies it (validate, and
        the machine's tuning.MachineTuning.check)."""
        check_runtime_names(changes)
        for name, value in changes.items():
            default = getattr(ControllerConfig, name)
            if isinstance(default, str) != isinstance(value, str) or isinstance(value, bool):
                raise FieldError.out_of_range(name, "a name" if isinstance(default, str) else "a number", value)
        return replace(self, **{k: (v if isinstance(v, str) else float(v)) for k, v in changes.items()})

    @classmethod
    def from_dict(cls, values: dict) -> "ControllerConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise FieldError(unknown[0], f"unknown controller parameter (known: {sorted(known)})")
        return cls(**values)


def check_runtime_names(changes) -> None:
    """``changes`` is a non-empty mapping of runtime settings (ValueError naming the first
    that is not one)."""
    if not isinstance(changes, dict) or not changes:
        raise FieldError("settings", "expected a non-empty mapping of name: value")
    unknown = sorted(set(changes) - set(RUNTIME_SETTINGS))
    if unknown:
        raise FieldError(unknown[0], f"cannot be changed while running (can: {list(RUNTIME_SETTINGS)})")
