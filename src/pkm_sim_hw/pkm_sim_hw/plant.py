"""The simulated machine (no rclpy): true geometry, dynamics, drives, encoders,
structural compliance, external load and faults.

* The real machine differs from the nominal model the controller knows: per-leg link
  length errors (ARCHI §4.1: 2 % on one leg) and rail offsets.
* State = platform pose and twist (task coordinates). Drive positions follow from the
  pose through the TRUE geometry, so the part of the drive forces in the null space of
  the true J^T moves nothing: it is internal force loading the structure (what
  "fighting" is); it is computed and reported every step.
* Dynamics: ARCHI §3.4, A(x) xddot + H(x, xdot) = J^T f_d + f_n (pkm_kinematics.dynamics),
  fixed step with substeps, semi-implicit Euler (default, one model evaluation) or RK4.
* The imperfect Delta (MoM3 §4.1, ``parallelogram_bar_errors_m``): each leg of a
  Delta a parallelogram of two bars of their own lengths (pkm_kinematics.parallelogram).
  The platform then turns with its position (a parasitic rotation of a few mrad): the
  drives read the imperfect machine's actuator values and the tool pose carries its
  rotation (``PlantOutput.tool_rotation``), which a Gough metrology measures and the
  encoders cannot. The dynamics keep the perfect Delta's J_m (the bars change it by
  their relative error, ~1e-4).
* Drives: force saturation; faults ``no_force`` (the drive applies nothing) and
  ``locked`` (a brake holds it: a constraint J_i xdot = 0 with its reaction force).
* Encoders: quantised at the resolution, optional Gaussian noise, velocity by backward
  difference; fault ``encoder_freeze`` holds the last reading, ``encoder_slip`` adds a
  constant offset (the fault's size, default 100 um) from its start on.
* Compliance: the tool deflects by C f_load, invisible to the drive encoders and
  visible to a metrology on the tool (MoM3 §7.1: ~70-80 um under 110 N). A load on the
  machine's frame (``frame_load``, MoM3 §7.1.2: 850 N) moves the whole actuation chain
  by C_frame f_frame, the tool with it: invisible to the encoders too, visible to a
  metrology whose base is not on that frame (the Gough's, MoM3 Table 3).
* External load: bounded by ``max_load_n`` (force components) and ``max_load_nm``
  (moment components); a larger one is refused (ValueError naming the bound).
* Safe stop: brakes on every drive (the platform stops and holds), commands ignored;
  the stop keeps its reason and its ``TripCause``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from pkm_common.causes import TripCause
from pkm_common.cdr import in_order
from pkm_kinematics.config import MachineConfig
from pkm_kinematics.distribution import internal_force_rows
from pkm_kinematics.errors import FieldError, KinematicsError
from pkm_kinematics.dynamics import DynamicModel
from pkm_kinematics.parallelogram import ParallelogramMachine
from pkm_kinematics.rails import RailMachine
from pkm_kinematics.task_space import POSITION, TaskSpace, load_components
from pkm_kinematics.validation import finite_floats

from .drives import Encoders, applied_forces, take_commands
from .rail_step import (IN_FRAME_LOAD, IN_LOAD, IN_SIZE, IN_V, IN_X, K_DRIVES, OUT_DRIVES, OUT_TOOL, OUT_V,
                        OUT_X, STEP_OK, rail_step)
from .structure import deflected

_deflected = deflected.py_func

FAULT_KINDS = ("no_force", "locked", "encoder_freeze", "encoder_slip")
DEFAULT_SLIP_M = 1e-4


@dataclass(frozen=True)
class Fault:
    """A drive fault that starts at ``at_s`` (simulated time); ``size``: the offset of
    an ``encoder_slip`` (m)."""

    drive: int
    kind: str
    at_s: float = 0.0
    size: float = 0.0

    @staticmethod
    def parse(text: str, n_drives: int) -> "Fault":
        """``"<drive>:<kind>[:<at_s>[:<size>]]"``, drive counted from 0, e.g.
        ``"2:locked:0.5"``, ``"1:encoder_slip:0.3:2e-4"``."""
        parts = text.split(":")
        try:
            drive, kind = int(parts[0]), parts[1]
            at_s = float(parts[2]) if len(parts) > 2 else 0.0
            size = float(parts[3]) if len(parts) > 3 else (DEFAULT_SLIP_M if kind == "encoder_slip" else 0.0)
        except (IndexError, ValueError):
            raise FieldError("faults", f"expected '<drive>:<kind>[:<at_s>[:<size>]]', got {text!r}") from None
        if len(parts) > 4 or (len(parts) > 3 and kind != "encoder_slip"):
            raise FieldError("faults", f"only encoder_slip takes a size, got {text!r}")
        if not 0 <= drive < n_drives:
            raise FieldError("faults", f"drive must be in [0, {n_drives - 1}], got {drive} in {text!r}")
        if kind not in FAULT_KINDS:
            raise FieldError("faults", f"kind must be one of {list(FAULT_KINDS)}, got {kind!r}")
        if not (at_s >= 0.0 and math.isfinite(at_s)):
            raise FieldError("faults", f"start time must be in [0, inf) s, got {at_s}")
        if not (math.isfinite(size) and abs(size) <= 0.01):
            raise FieldError("faults", f"slip size must be in [-0.01, 0.01] m, got {size}")
        return Fault(drive, kind, at_s, size)


@dataclass
class PlantParameters:
    """How the simulated machine differs from and adds to the nominal model."""

    dt_s: float = 0.001
    substeps: int = 1
    integrator: str = "semi_implicit"
    force_limit_n: float = 2000.0
    encoder_resolution_m: float = 1e-6
    encoder_noise_m: float = 0.0
    seed: int = 0
    link_length_errors: tuple = ()        # relative, per leg, e.g. (0, 0, 0.02, 0)
    rail_offset_errors_m: tuple = ()      # shift of each rail origin along its rail
    encoder_offsets_m: tuple = ()         # incremental encoders' offsets until homed, one per drive (drives.Encoders)
    screw_errors_m: tuple = ()            # each drive's screw error amplitude (drives.Encoders), one per drive
    screw_error_period_m: float = 0.1     # and its period along the travel
    compliance: tuple = (0.0, 0.0, 0.0)   # diagonal C in task coordinates (m/N, m/N, m/N or rad/(N m))
    frame_compliance: tuple = (0.0, 0.0, 0.0)   # diagonal C_frame: the actuation chain's frame under frame_load
    faults: tuple = ()
    max_load_n: float = 5000.0            # bound of each force component of the external load
    max_load_nm: float = 500.0            # bound of a moment component (planar machines: m_z)
    parallelogram_bar_errors_m: tuple = ()     # a Delta's bars: 6 length errors (m), two per leg (MoM3 §4.1)
    parallelogram_half_width_m: float = 0.03   # half the distance between a parallelogram's two bars

    def validate(self, n_drives: int, space: TaskSpace | None = None) -> None:
        """ValueError naming the first parameter out of its range, for a machine of
        ``n_drives`` drives in the task space ``space`` (None: not known)."""
        if space is not None and not isinstance(space, TaskSpace):
            raise TypeError(f"space: a pkm_kinematics.task_space.TaskSpace or None, got {space!r}")
        checks = [("dt_s", self.dt_s > 0.0 and self.dt_s <= 0.1, "(0, 0.1] s"),
                  ("substeps", 1 <= self.substeps <= 1000, "[1, 1000]"),
                  ("integrator", self.integrator in ("semi_implicit", "rk4"), "semi_implicit or rk4"),
                  ("force_limit_n", self.force_limit_n > 0.0, "(0, inf) N"),
                  ("encoder_resolution_m", 0.0 <= self.encoder_resolution_m <= 1e-3, "[0, 1e-3] m"),
                  ("encoder_noise_m", self.encoder_noise_m >= 0.0, "[0, inf) m"),
                  ("link_length_errors", len(self.link_length_errors) in (0, n_drives)
                   and all(abs(e) < 0.5 for e in self.link_length_errors), f"{n_drives} values in (-0.5, 0.5)"),
                  ("rail_offset_errors_m", len(self.rail_offset_errors_m) in (0, n_drives), f"{n_drives} values"),
                  ("screw_errors_m", len(self.screw_errors_m) in (0, n_drives)
                   and all(abs(a) <= 1e-3 for a in self.screw_errors_m), f"{n_drives} values in [-1e-3, 1e-3] m"),
                  ("screw_error_period_m", 1e-3 <= self.screw_error_period_m <= 10.0, "[0.001, 10] m"),
                  ("encoder_offsets_m", len(self.encoder_offsets_m) in (0, n_drives)
                   and all(abs(o) <= 1.0 for o in self.encoder_offsets_m), f"{n_drives} values in [-1, 1] m"),
                  ("compliance", len(self.compliance) in (3, 6) and all(c >= 0.0 for c in self.compliance),
                   "3 values >= 0 (6 on a 6-DOF machine)"),
                  ("frame_compliance", len(self.frame_compliance) in (3, 6)
                   and all(c >= 0.0 for c in self.frame_compliance), "3 values >= 0 (6 on a 6-DOF machine)"),
                  ("max_load_n", 0.0 < self.max_load_n < math.inf, "(0, inf) N"),
                  ("max_load_nm", 0.0 < self.max_load_nm < math.inf, "(0, inf) N m"),
                  ("parallelogram_bar_errors_m", not self.parallelogram_bar_errors_m
                   or (len(self.parallelogram_bar_errors_m) == 6 and n_drives == 3 and space in (None, POSITION)
                       and all(abs(e) <= 0.01 for e in self.parallelogram_bar_errors_m)),
                   "empty, or 6 values in [-0.01, 0.01] m (two bars per leg) on a Delta (3 rails)"),
                  ("parallelogram_half_width_m", 0.0 < self.parallelogram_half_width_m <= 1.0, "(0, 1] m")]
        for name, ok, allowed in checks:
            if not ok:
                raise FieldError(name, f"must be {allowed}, got {getattr(self, name)!r}")


@dataclass
class PlantOutput:
    """What one step produces (the node turns it into messages)."""

    time_s: float
    step: int
    stamp_ns: int                  # the step's stamp: step * dt (int ns), as published
    encoder_positions: list        # quantised drive positions (m), frozen ones held
    encoder_velocities: list       # backward difference of the encoder positions (m/s)
    applied_forces: list           # forces the drives actually apply (N); locked: brake reaction
    saturated: list                # bool per drive
    tool_pose: list                # task coordinates of the tool, deflection included
    rigid_pose: list               # the platform pose without the deflection
    internal_force: list           # null-space part of the applied forces (N)
    internal_force_norm: float
    faults_active: list = field(default_factory=list)
    stopped: bool = False
    tool_rotation: tuple | None = None     # row-major 9: the tool's rotation where it is not the task's


def true_machine(nominal, link_length_errors=(), rail_offset_errors_m=()):
    """The nominal machine with per-leg link length errors (relative) and rail offsets."""
    legs = list(nominal.legs)
    for i, leg in enumerate(legs):
        err = link_length_errors[i] if link_length_errors else 0.0
        off = rail_offset_errors_m[i] if rail_offset_errors_m else 0.0
        direction = np.asarray(leg.rail_direction, dtype=float)
        origin = np.asarray(leg.rail_origin, dtype=float) + off * direction / np.linalg.norm(direction)
        legs[i] = dataclasses.replace(leg, link_length=leg.link_length * (1.0 + err),
                                      rail_origin=tuple(origin.tolist()))
    return nominal.with_legs(nominal.name + "_true", legs)


class Plant:
    """One simulated machine; ``step(forces)`` advances by ``dt_s``."""

    def __init__(self, config: MachineConfig, params: PlantParameters | None = None, initial_pose=None):
        if config.dynamics is None:
            raise ValueError(f"machine {config.name!r}: the plant needs a 'dynamics' section")
        self.params = params or PlantParameters()
        n = config.model.n_legs
        self.params.validate(n, config.model.task_space)
        for name in ("compliance", "frame_compliance"):
            if len(getattr(self.params, name)) != 3:
                raise FieldError(name, f"must be 3 values on a 3-DOF machine, got {list(getattr(self.params, name))}")
        self.config = config
        self.n = n
        self.names = list(config.model.leg_names)
        self.machine = true_machine(config.model, self.params.link_length_errors, self.params.rail_offset_errors_m)
        self.dynamics = DynamicModel(self.machine, config.dynamics)
        # a machine on rails integrated semi-implicitly, no drive locked: the whole
        # integration and the outputs' velocity terms in one compiled call, the same
        # floats as _integrate (tests/sim_hw compares the two: set it False for the
        # Python path); rk4 and locked drives take the Python path
        self.compiled_step = self.params.integrator == "semi_implicit" and isinstance(self.machine, RailMachine)
        home = config.model.home
        self.x = finite_floats(home if initial_pose is None else initial_pose, 3, "initial_pose")
        self.machine.inverse_kinematics(self.x)          # reachable with the true geometry
        self.bars = None                                 # the imperfect Delta's bars (module doc)
        if self.params.parallelogram_bar_errors_m:
            self.bars = ParallelogramMachine(self.machine.name + "_bars", self.machine.legs,
                                             self.params.parallelogram_half_width_m,
                                             self.params.parallelogram_bar_errors_m, self.x, self.machine.workspace)
        self.v = [0.0, 0.0, 0.0]
        self.t = 0.0
        self.k = 0
        self.dt_ns = round(self.params.dt_s * 1e9)      # a step's stamp is k * dt_ns
        self.load = [0.0, 0.0, 0.0]
        self.frame_load = [0.0, 0.0, 0.0]
        self._schedule: list = []          # [(step, wrench)] (schedule_load)
        self._frame_schedule: list = []    # [(step, wrench)] (schedule_frame_load)
        self._schedule_all, self._frame_schedule_all = [], []     # as loaded (restart_clock)
        self.schedules_paused = False      # before the run (homing): no scheduled load
        self.homed = not self.params.encoder_offsets_m    # incremental encoders: not until homing.home
        self.stopped = False
        self.stop_reason = ""
        self.stop_cause = TripCause.NONE
        self._faults = [Fault.parse(f, n) if isinstance(f, str) else f for f in self.params.faults]
        self._lower = self.machine.joint_lower.tolist()
        self._upper = self.machine.joint_upper.tolist()
        self._locked: list[int] = []
        self._lock_positions: dict[int, float] = {}
        self.encoders = Encoders(self.params.encoder_resolution_m, self.params.encoder_noise_m, self.params.seed,
                                 self.params.dt_s, self.params.encoder_offsets_m, self.params.screw_errors_m,
                                 self.params.screw_error_period_m)
        self.encoders.start(self._drive_positions(self.machine.inverse_kinematics(self.x, check_limits=False).tolist())[0])
        self._last = self._output([0.0] * n, [False] * n, self.active_faults())
        # the common case compiled whole (rail_step.py); ``compiled_step`` False: never
        self._compiled = _CompiledStep(self) if self.compiled_step and self.bars is None and not self._faults \
            else None

    # ------------------------------------------------------------------ inputs
    def check_load(self, wrench, what: str = "load") -> list:
        """The external load as 3 floats, or ValueError naming the bound it exceeds
        (``max_load_n`` per force component, ``max_load_nm`` per moment component)."""
        return check_load(wrench, self.config.model.task_space, self.params, what)

    def load_components(self, force, moment) -> list:
        """The load of a wrench (force, moment: 3 each, world frame) in this machine's
        task coordinates: fx, fy, mz on a planar machine, fx, fy, fz otherwise."""
        return load_components(self.config.model.task_space, force, moment)

    def set_load(self, wrench) -> None:
        """External (cutting) load on the tool, task coordinates (N, N, N m | N);
        ValueError (nothing applied) over its bound."""
        self.load = self.check_load(wrench)

    def schedule_load(self, rows, what: str = "load_schedule") -> None:
        """Loads on the tool in simulated time: [(t_s, wrench)], times non-decreasing;
        each applies from the first step at or after t_s (counted in steps: no float drift).
        ``what`` names them in a refusal (the parameter they came from)."""
        self._schedule = self._steps(rows, what)
        self._schedule_all = list(self._schedule)

    def schedule_frame_load(self, rows, what: str = "frame_load_schedule") -> None:
        """Loads on the machine's frame in simulated time, as :meth:`schedule_load`."""
        self._frame_schedule = self._steps(rows, what)
        self._frame_schedule_all = list(self._frame_schedule)

    def _steps(self, rows, what: str) -> list:
        return load_steps(rows, self.params.dt_s, self.check_load, what)

    def safe_stop(self, reason: str, cause: TripCause = TripCause.PLANT_SAFE_STOP) -> None:
        """Brakes on: the platform stops where it is and holds; commands are ignored.
        The first stop's reason and cause are kept."""
        if not self.stopped:
            self.stopped, self.stop_reason, self.stop_cause = True, reason, TripCause(cause)
        self.v = [0.0, 0.0, 0.0]

    def active_faults(self) -> list[Fault]:
        return [f for f in self._faults if f.at_s <= self.t + 1e-12]

    def restart_clock(self) -> None:
        """Simulated time 0 here (the state kept): a run that starts after the machine's
        homing counts its steps, load schedules and faults from its own start (no load
        before it)."""
        self.k, self.t = 0, 0.0
        self._schedule, self._frame_schedule = list(self._schedule_all), list(self._frame_schedule_all)
        self.load, self.frame_load = [0.0] * len(self.load), [0.0] * len(self.frame_load)
        self.schedules_paused = False
        self._last = self._output([0.0] * self.n, [False] * self.n, self.active_faults())

    def pause_schedules(self) -> None:
        """No scheduled load until restart_clock (the machine homes before its run)."""
        self.schedules_paused = True

    # ------------------------------------------------------------------- step
    def step(self, forces, hold: bool = False) -> PlantOutput:
        """Apply the commanded drive forces for one period and advance the state;
        ``hold``: the drives' holding brakes are closed for this period (a drive whose
        power stage is off: pkm_drives.virtual_drive), the platform stays where it is,
        without latching a stop."""
        if self._compiled is not None and self.compiled_step and not (self.stopped or hold):
            out = self._compiled.step(forces)
            if out is not None:
                return out
        cmd = finite_floats(forces, self.n, "drive forces")
        self._apply_schedules()
        faults = self.active_faults()
        applied, saturated = applied_forces(cmd, self.params.force_limit_n, faults)
        locked = sorted({f.drive for f in faults if f.kind == "locked"})
        if len(locked) >= 3 and not self.stopped:
            # three or more brakes fix the platform (3 DOF): hold it, the reactions are
            # statically indeterminate on a redundant machine
            self.safe_stop(f"drives {', '.join(self.names[i] for i in locked)} locked")
        elif locked != self._locked:
            q = self.machine.inverse_kinematics(self.x, check_limits=False)
            self._lock_positions = {i: self._lock_positions.get(i, float(q[i])) for i in locked}
            self._locked = locked
            try:
                self._project_velocity()
            except np.linalg.LinAlgError:
                self.safe_stop("locked drives: singular constraint")
        h = self.params.dt_s / self.params.substeps
        reaction = [0.0] * self.n
        terms = None
        if hold:
            self.v = [0.0, 0.0, 0.0]
        if not (self.stopped or hold):
            saved = (self.x, self.v)
            try:
                if self.compiled_step and not self._locked and self.params.integrator == "semi_implicit":
                    self.x, self.v, terms = self.dynamics.semi_implicit_step(self.x, self.v, applied, self.load, h,
                                                                             self.params.substeps)
                else:
                    for _ in range(self.params.substeps):
                        reaction = self._integrate(applied, h)
                        if self._locked:
                            self._hold_locked_drives()
                    terms = self.machine.velocity_terms(self.x, self.v)
                for i, (qi, lo, hi) in enumerate(zip(terms[0], self._lower, self._upper)):
                    if not lo <= qi <= hi:
                        raise KinematicsError(f"drive {self.names[i]} reached its end stop ({qi:.6g} m)")
            except (KinematicsError, np.linalg.LinAlgError) as exc:
                # the machine cannot go there (singularity, unreachable, end stop):
                # brakes on at the last valid state, reported as the stop reason
                self.x, self.v = saved
                self.safe_stop(f"left the workspace: {exc}")
                terms = None
        self.t += self.params.dt_s
        self.k += 1
        for i in self._locked:
            applied[i] += reaction[i]                # command + brake reaction act together
        if self.stopped or hold:
            applied = [0.0] * self.n
        self._last = self._output(applied, saturated, faults, terms)
        return self._last

    def _apply_schedules(self) -> None:
        """The scheduled loads due at this step."""
        while self._schedule and self.k >= self._schedule[0][0] and not self.schedules_paused:
            self.load = self._schedule.pop(0)[1]
        while self._frame_schedule and self.k >= self._frame_schedule[0][0] and not self.schedules_paused:
            self.frame_load = self._frame_schedule.pop(0)[1]

    def _acceleration(self, x, v, forces):
        """xddot, and the brake reactions of locked drives (constrained dynamics)."""
        if not self._locked:
            return self.dynamics.forward_dynamics(x, v, forces, self.load), None
        a, hvec, rows, _, _ = self.dynamics.terms(x, v)
        _, _, _, jdv = self.machine.velocity_terms(x, v)
        rhs = np.array(self.load) - np.array(hvec) + np.array(rows).T @ np.array(forces)
        jl = np.array([rows[i] for i in self._locked])
        m = len(self._locked)
        kkt = np.block([[np.array(a), -jl.T], [jl, np.zeros((m, m))]])
        # J_L xddot = -Jdot_L xdot keeps q_L constant; drift is removed after each step
        cons = [-jdv[i] for i in self._locked]
        sol = np.linalg.solve(kkt, np.concatenate([rhs, cons]))
        return sol[:3].tolist(), dict(zip(self._locked, sol[3:].tolist()))

    def _integrate(self, forces, h) -> list:
        x, v = self.x, self.v
        if self.params.integrator == "rk4":
            def f(xs, vs):
                acc, _ = self._acceleration(xs, vs, forces)
                return vs, acc
            k1 = f(x, v)
            k2 = f([a + 0.5 * h * b for a, b in zip(x, k1[0])], [a + 0.5 * h * b for a, b in zip(v, k1[1])])
            k3 = f([a + 0.5 * h * b for a, b in zip(x, k2[0])], [a + 0.5 * h * b for a, b in zip(v, k2[1])])
            k4 = f([a + h * b for a, b in zip(x, k3[0])], [a + h * b for a, b in zip(v, k3[1])])
            self.x = [a + h / 6.0 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in zip(x, k1[0], k2[0], k3[0], k4[0])]
            self.v = [a + h / 6.0 * (b + 2 * c + 2 * d + e) for a, b, c, d, e in zip(v, k1[1], k2[1], k3[1], k4[1])]
            reactions = self._acceleration(self.x, self.v, forces)[1]
        else:   # semi-implicit (symplectic) Euler: v += h a(x, v); x += h v
            acc, reactions = self._acceleration(x, v, forces)
            self.v = [a + h * b for a, b in zip(v, acc)]
            self.x = [a + h * b for a, b in zip(x, self.v)]
        out = [0.0] * self.n
        for i, r in (reactions or {}).items():
            out[i] = r
        return out

    def _hold_locked_drives(self) -> None:
        """Put locked drives back exactly where they locked (the integration drifts at
        second order): a minimum-norm Gauss-Newton correction of the pose, then the
        velocity projection."""
        for _ in range(3):
            q, rows, _, _ = self.machine.velocity_terms(self.x, self.v)
            err = np.array([self._lock_positions[i] - q[i] for i in self._locked])
            if np.abs(err).max() < 1e-13:
                break
            jl = np.array([rows[i] for i in self._locked])
            self.x = (np.array(self.x) + jl.T @ np.linalg.solve(jl @ jl.T, err)).tolist()
        self._project_velocity()

    def _project_velocity(self) -> None:
        """A brake engaging stops its drive at once: remove the velocity component that
        moves a locked drive, in the metric of the mass matrix (an impulse)."""
        if not self._locked:
            return
        a, _, rows, _, _ = self.dynamics.terms(self.x, self.v)
        jl = np.array([rows[i] for i in self._locked])
        a = np.array(a)
        ainv_jt = np.linalg.solve(a, jl.T)
        v = np.array(self.v)
        self.v = (v - ainv_jt @ np.linalg.solve(jl @ ainv_jt, jl @ v)).tolist()

    # ----------------------------------------------------------------- outputs
    def _drive_positions(self, q_rigid) -> tuple[list, tuple | None]:
        """The drives' true positions and the tool's rotation: the imperfect Delta's
        when its bars are given, else the rigid model's q and None."""
        if self.bars is None:
            return q_rigid, None
        pose = self.bars.inverse_kinematics_full(self.x)
        return pose.q.tolist(), tuple(pose.rotation.ravel().tolist())

    def _output(self, applied, saturated, faults, terms=None) -> PlantOutput:
        q_rigid, rows, _, _ = terms or self.machine.velocity_terms(self.x, self.v)
        q_true, rotation = self._drive_positions(q_rigid)
        reading, velocity = self.encoders.read(q_true, faults)
        fint = internal_force_rows(rows, applied) if self.n > 3 else [0.0] * self.n
        c, cf = self.params.compliance, self.params.frame_compliance
        tool = [_deflected(*terms) for terms in zip(self.x, c, self.load, cf, self.frame_load)]
        return PlantOutput(self.t, self.k, self.k * self.dt_ns, reading, velocity, list(applied), saturated, tool,
                           list(self.x), fint, math.sqrt(sum(f * f for f in fint)),
                           [f"{f.drive}:{f.kind}" for f in faults], self.stopped, rotation)

    def output(self) -> PlantOutput:
        """The outputs of the last step (or of the initial state)."""
        return self._last


class _CompiledStep:
    """Plant.step of a rail machine without faults or bars, compiled whole
    (rail_step.py): the plant's state copied in and out of arrays around two kernel
    calls. ``step`` returns None where the interpreted step must be taken (a command
    that is not n finite numbers, an end stop, a pose the kinematics refuses): nothing
    has changed then."""

    def __init__(self, plant: Plant):
        n, p = plant.n, plant.params
        self.plant = plant
        self.bars, self.columns, md, k, dg, *mass = plant.dynamics.step_arguments()
        self.constants = np.array([p.force_limit_n, p.dt_s / p.substeps, int(p.substeps), *mass, *p.compliance,
                                   *p.frame_compliance, *md, *k, *dg, *plant._lower, *plant._upper], dtype=float)
        assert len(self.constants) == K_DRIVES + 5 * n
        self.cmd, self.inputs, self.out = np.empty(n), np.empty(IN_SIZE), np.empty(OUT_DRIVES + 5 * n)
        self.rows, self.saturated = np.empty((n, 3)), np.zeros(n, dtype=bool)
        self.encoder, self.encoder_args = np.empty(3), None
        self.made, self.loads = (None, None), (None, None)      # what step() copied from and made (step)

    def step(self, forces) -> PlantOutput | None:
        plant, cmd = self.plant, self.cmd
        if not take_commands(cmd, forces):
            return None                              # refused by the interpreted step, naming it, nothing changed
        plant._apply_schedules()
        inputs, out, n = self.inputs, self.out, plant.n
        # the state and the loads copied in when they are not the lists this step made
        # last (or set once): the values in ``out`` and ``inputs`` already
        x, v, load, frame_load = plant.x, plant.v, plant.load, plant.frame_load
        if x is self.made[0] and v is self.made[1]:
            inputs[IN_X:IN_X + 6] = out[OUT_X:OUT_X + 6]
        else:
            inputs[IN_X:IN_X + 3], inputs[IN_V:IN_V + 3] = x, v
        if load is not self.loads[0] or frame_load is not self.loads[1]:
            inputs[IN_LOAD:IN_LOAD + 3], inputs[IN_FRAME_LOAD:IN_FRAME_LOAD + 3] = load, frame_load
            self.loads = (load, frame_load)
        enc = plant.encoders
        encoder_args = enc.kernel_arguments()       # the same tuple until homing changes them
        if encoder_args is not self.encoder_args:
            self.encoder_args = encoder_args
            self.encoder[:] = (encoder_args[0], encoder_args[3], enc.dt_s)
        code, norm = rail_step(cmd, inputs, self.constants, self.bars, self.columns, self.encoder, encoder_args[1],
                               encoder_args[2], enc.noise(n), enc.last_array(), out, self.rows, self.saturated)
        if code != STEP_OK:
            self.made = (None, None)                 # ``out`` may be written in part
            return None
        plant.x, plant.v = self.made = out[OUT_X:OUT_X + 3].tolist(), out[OUT_V:OUT_V + 3].tolist()
        plant.t += plant.params.dt_s
        plant.k += 1
        drives = out[OUT_DRIVES:]
        reading = enc.keep(drives[3 * n:4 * n])
        plant._last = PlantOutput(plant.t, plant.k, plant.k * plant.dt_ns, reading, drives[4 * n:].tolist(),
                                  drives[:n].tolist(), self.saturated.tolist(), out[OUT_TOOL:OUT_TOOL + 3].tolist(),
                                  list(plant.x), drives[2 * n:3 * n].tolist(), norm, [], plant.stopped, None)
        return plant._last


def check_load(wrench, space: TaskSpace, params: PlantParameters, what: str = "load") -> list:
    """An external load in the components of the task space ``space.loads`` (fx, fy,
    mz on a planar machine, fx, fy, fz on a translational one, fx ... mz on a spatial
    one) as floats, or ValueError naming the component and its bound."""
    values = finite_floats(wrench, len(space.loads), what)
    for label, value in zip(space.loads, values):
        bound, unit, name = (params.max_load_nm, "N m", "max_load_nm") if label[0] == "m" else \
            (params.max_load_n, "N", "max_load_n")
        if abs(value) > bound:
            raise FieldError(what, f"{label} must be in [-{bound:g}, {bound:g}] {unit} ({name}), got {value:g}")
    return values


def load_steps(rows, dt_s: float, check, what: str) -> list:
    """[(step, load)] of loads in simulated time [(t_s, wrench)]: each from the first
    step at or after t_s (counted in steps: no float drift), times non-decreasing,
    each load through ``check(wrench, what)``."""
    schedule, last_t = [], 0.0
    for t, wrench in rows:
        if not (math.isfinite(t) and t >= 0.0) or t < last_t - 1e-12:
            raise FieldError(what, f"times must be finite, >= 0 and non-decreasing, got {t}")
        schedule.append((math.ceil(t / dt_s - 1e-6), check(wrench, what)))
        last_t = t
    return schedule


def leg_segments(machine, x) -> list[tuple[list, list]]:
    """(carriage, platform joint) points of every leg in world coordinates (3-D; z = 0
    for planar machines), for visualisation markers and the operator panel."""
    carriages, joints = machine.leg_joints(x)
    return [(a.tolist(), b.tolist()) for a, b in zip(carriages, joints)]


def command_efforts(msg, names) -> tuple[list | None, str]:
    """(efforts in the order of ``names``, "") of a drives/command read from its bytes
    (pkm_common.cdr.JointStateData), or (None, why it is refused): names that are not
    the drives', a wrong count, NaN or inf."""
    try:
        effort = list(in_order(msg, names).effort)
    except ValueError:                        # names that are not the plant's
        effort = None
    if effort is None or len(effort) != len(names):
        return None, f"expected {len(names)} efforts for {list(names)}, got {len(msg.effort)} for {list(msg.name)}"
    if not math.isfinite(sum(effort)):        # NaN or inf in any of them
        return None, f"non-finite effort {effort}"
    return effort, ""
