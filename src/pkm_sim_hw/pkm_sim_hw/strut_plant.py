"""The simulated hexapod (no rclpy): a platform on actuated struts in SE(3), the plant
of the strut machines (``kind: struts``: genhexkins, hexapod8).

* State: the pose (p, R) and the twist t = (v, w), w in the base frame.
* Dynamics: Newton-Euler, ``A t' + H = J_m^T f_d + f_n`` (pkm_kinematics.rigid_body,
  the machine's ``dynamics`` section), integrated semi-implicitly like the rail
  machines' plant: t += h t'(x, t); p += h v; R = exp(h [w]x) R (the rotation stays
  orthonormal: no angles are integrated).
* Drives and encoders as every plant's (``drives``): saturation, ``no_force``,
  quantised encoders, ``encoder_freeze`` and ``encoder_slip``. ``link_length_errors``
  (relative, per strut) is a strut's measuring error: strut k is (1 + e_k) times as
  long as its encoder reads (a screw's pitch error), so the controller's nominal model
  sees an inconsistent set of lengths (a redundant machine's drives fight over it). A
  strut at its end stop, a singular pose or a fault the model cannot take
  (``locked``: a brake on a strut) brakes the machine: the platform stops where it is.
* External load: a wrench (force, moment about p, base frame), bounded by
  ``max_load_n`` / ``max_load_nm`` per component, set now (the load topic) or
  scheduled in simulated time (a scenario's load). ``compliance`` (6 values: m/N for
  the forces, rad/(N m) for the moments) deflects the tool by C f_load in task
  coordinates, invisible to the strut encoders (the rigid platform does not move).
  A load on the machine's frame (``frame_load``, MoM3 §7.1.2) moves the whole
  actuation chain, base joints and platform, by C_frame f_frame (``frame_compliance``,
  6 values): the tool with it, unseen by the struts, seen by a metrology whose base
  is not on that frame (the Gough's).
Outputs are the rail machines' ``PlantOutput``: the tool pose as the six task
coordinates (x, y, z, a, b, c), its rotation row-major in ``tool_rotation``.
Not yet: the rail plant's rail offsets (refused when set).
sim_hw runs it for a strut machine (``parameters.PLANTS``).
"""

from __future__ import annotations

import math

import numpy as np

from pkm_common.causes import TripCause
from pkm_kinematics.config import MachineConfig
from pkm_kinematics.distribution import internal_force
from pkm_kinematics.errors import FieldError, KinematicsError, SingularityError
from pkm_kinematics.rigid_body import StrutDynamics
from pkm_kinematics.rotations import rotation_from_rpy
from pkm_kinematics.task_space import load_components
from pkm_kinematics.validation import finite_floats

from .drives import Encoders, applied_forces, take_commands
from .plant import Fault, PlantOutput, PlantParameters, check_load, load_steps
from .strut_step import STEP_OK, strut_dynamics_step, strut_outputs
from .structure import deflected

_deflected = deflected.py_func

_NOT_YET = ("rail_offset_errors_m", "parallelogram_bar_errors_m")


class StrutPlant:
    """One simulated strut machine; ``step(forces)`` advances by ``dt_s``."""

    def __init__(self, config: MachineConfig, params: PlantParameters | None = None, initial_pose=None):
        if config.dynamics is None:
            raise ValueError(f"machine {config.name!r}: the plant needs a 'dynamics' section")
        self.params = params or PlantParameters()
        self.machine = config.model
        self.n = self.machine.n_legs
        self.params.validate(self.n, config.model.task_space)
        for name in _NOT_YET:
            if any(getattr(self.params, name)):
                raise FieldError(name, f"not simulated on a strut machine yet (leave it empty or zero)")
        for name in ("compliance", "frame_compliance"):
            values = getattr(self.params, name)
            if any(values) and len(values) != 6:
                raise FieldError(name, f"must be 6 values on a 6-DOF machine (m/N for fx fy fz, rad/(N m) for "
                                       f"mx my mz), got {list(values)}")
        self._compliance = np.array(self.params.compliance if any(self.params.compliance) else [0.0] * 6)
        self._frame_compliance = np.array(self.params.frame_compliance if any(self.params.frame_compliance)
                                          else [0.0] * 6)
        if self.params.integrator != "semi_implicit":
            raise FieldError("integrator", f"a strut machine integrates semi_implicit only, got "
                                           f"{self.params.integrator!r}")
        self.names = list(self.machine.leg_names)
        self.dynamics = StrutDynamics(self.machine, config.dynamics)
        x0 = finite_floats(self.machine.home if initial_pose is None else initial_pose, 6, "initial_pose")
        self.p, self.rotation = self.machine.pose(x0)
        self.twist = np.zeros(6)
        self.load = np.zeros(6)
        self.frame_load = np.zeros(6)
        self._schedule: list = []          # [(step, load)] (schedule_load)
        self._frame_schedule: list = []    # [(step, load)] (schedule_frame_load)
        self._schedule_all, self._frame_schedule_all = [], []     # as loaded (restart_clock)
        self.schedules_paused = False      # before the run (homing): no scheduled load
        self.homed = not self.params.encoder_offsets_m    # incremental encoders: not until homing.home
        self.t, self.k = 0.0, 0
        self.dt_ns = round(self.params.dt_s * 1e9)      # a step's stamp is k * dt_ns
        self.stopped, self.stop_reason, self.stop_cause = False, "", TripCause.NONE
        self._faults = [Fault.parse(f, self.n) if isinstance(f, str) else f for f in self.params.faults]
        q = self.machine.strut_lengths(self.p, self.rotation)
        if not self.machine.within_joint_limits(q):
            raise FieldError("initial_pose", f"struts outside their limits: {np.round(q, 6).tolist()} m")
        self.encoders = Encoders(self.params.encoder_resolution_m, self.params.encoder_noise_m, self.params.seed,
                                 self.params.dt_s, self.params.encoder_offsets_m, self.params.screw_errors_m,
                                 self.params.screw_error_period_m)
        self._reading_scale = 1.0 / (1.0 + np.asarray(self.params.link_length_errors or [0.0] * self.n, dtype=float))
        self.encoders.start((q * self._reading_scale).tolist())
        self._last = self._output([0.0] * self.n, [False] * self.n, self.active_faults())
        # the common case compiled (strut_step.py); ``compiled_step`` False: never
        self.compiled_step = True
        self._compiled = _CompiledStrutStep(self) if not self._faults and not (
            self._compliance.any() or self._frame_compliance.any()) else None

    @property
    def x(self) -> list:
        """The task coordinates (x, y, z, a, b, c) of the platform."""
        return self.machine.task_coordinates(self.p, self.rotation).tolist()

    # ------------------------------------------------------------------ inputs
    def load_components(self, force, moment) -> list:
        """The load of a wrench (force, moment about p: 3 each, base frame): all six."""
        return load_components(self.machine.task_space, force, moment)

    def check_load(self, wrench, what: str = "load") -> list:
        """The load as 6 floats (fx, fy, fz in N, mx, my, mz in N m), or ValueError
        naming the component over its bound."""
        return check_load(wrench, self.machine.task_space, self.params, what)

    def schedule_load(self, rows, what: str = "load_schedule") -> None:
        """Loads on the platform in simulated time: [(t_s, wrench)], as the rail plant's."""
        self._schedule = load_steps(rows, self.params.dt_s, self.check_load, what)
        self._schedule_all = list(self._schedule)

    def schedule_frame_load(self, rows, what: str = "frame_load_schedule") -> None:
        """Loads on the machine's frame in simulated time, as :meth:`schedule_load`."""
        self._frame_schedule = load_steps(rows, self.params.dt_s, self.check_load, what)
        self._frame_schedule_all = list(self._frame_schedule)

    def set_load(self, wrench) -> None:
        """External load on the platform (fx, fy, fz in N, mx, my, mz in N m, base
        frame); ValueError naming the component over its bound (nothing applied)."""
        self.load = np.array(self.check_load(wrench))

    def safe_stop(self, reason: str, cause: TripCause = TripCause.PLANT_SAFE_STOP) -> None:
        """Brakes on: the platform stops where it is; the first stop's cause is kept."""
        if not self.stopped:
            self.stopped, self.stop_reason, self.stop_cause = True, reason, TripCause(cause)
        self.twist = np.zeros(6)

    def active_faults(self) -> list[Fault]:
        return [f for f in self._faults if f.at_s <= self.t + 1e-12]

    def restart_clock(self) -> None:
        """Simulated time 0 here, the state kept, the load schedules from their start
        (plant.Plant.restart_clock)."""
        self.k, self.t = 0, 0.0
        self._schedule, self._frame_schedule = list(self._schedule_all), list(self._frame_schedule_all)
        self.load, self.frame_load = np.zeros(6), np.zeros(6)
        self.schedules_paused = False
        self._last = self._output([0.0] * self.n, [False] * self.n, self.active_faults())

    def pause_schedules(self) -> None:
        """No scheduled load until restart_clock (the machine homes before its run)."""
        self.schedules_paused = True

    # ------------------------------------------------------------------- step
    def step(self, forces, hold: bool = False) -> PlantOutput:
        """Apply the commanded strut forces for one period and advance the state;
        ``hold``: the holding brakes are closed for this period (plant.Plant.step)."""
        if self._compiled is not None and self.compiled_step and not (self.stopped or hold):
            out = self._compiled.step(forces)
            if out is not None:
                return out
        cmd = finite_floats(forces, self.n, "drive forces")
        self._apply_schedules()
        faults = self.active_faults()
        applied, saturated = applied_forces(cmd, self.params.force_limit_n, faults)
        locked = [f for f in faults if f.kind == "locked"]
        if locked and not self.stopped:
            self.safe_stop(f"drive {self.names[locked[0].drive]} locked (a brake on a strut: the machine holds)")
        q = None
        if hold:
            self.twist = np.zeros(6)
        if not (self.stopped or hold):
            try:        # semi-implicit Euler on SE(3): t += h t'; p += h v; R = exp(h w) R (compiled)
                p, rotation, twist = self.dynamics.step(self.p, self.rotation, self.twist, applied, self.load,
                                                        self.params.dt_s / self.params.substeps,
                                                        self.params.substeps)
                q = self.machine.strut_lengths(p, rotation)
                for i in np.flatnonzero((q < self.machine.joint_lower) | (q > self.machine.joint_upper)):
                    raise KinematicsError(f"drive {self.names[i]} reached its end stop ({q[i]:.6g} m)")
                self.p, self.rotation, self.twist = p, rotation, twist
            except (KinematicsError, SingularityError, np.linalg.LinAlgError) as exc:
                q = None
                self.safe_stop(f"left the workspace: {exc}")
        self.t += self.params.dt_s
        self.k += 1
        if self.stopped or hold:
            applied = [0.0] * self.n
        self._last = self._output(applied, saturated, faults, q)
        return self._last

    def _apply_schedules(self) -> None:
        """The scheduled loads due at this step."""
        while self._schedule and self.k >= self._schedule[0][0] and not self.schedules_paused:
            self.load = np.array(self._schedule.pop(0)[1])
        while self._frame_schedule and self.k >= self._frame_schedule[0][0] and not self.schedules_paused:
            self.frame_load = np.array(self._frame_schedule.pop(0)[1])

    # ----------------------------------------------------------------- outputs
    def _output(self, applied, saturated, faults, lengths=None) -> PlantOutput:
        """The outputs of the current state (``lengths``: its strut lengths, if known)."""
        lengths = self.machine.strut_lengths(self.p, self.rotation) if lengths is None else lengths
        q = (lengths * self._reading_scale).tolist()
        reading, velocity = self.encoders.read(q, faults)
        x = self.x
        fint = internal_force(self.machine.jacobian(x), applied).tolist() if self.n > 6 else [0.0] * self.n
        tool, rotation = list(x), self.rotation
        if self._compliance.any() or self._frame_compliance.any():
            # the tool deflected by C f_load and carried by the frame's C_frame f_frame: unseen by the struts
            tool = [_deflected(*terms) for terms in zip(x, self._compliance.tolist(), self.load.tolist(),
                                                        self._frame_compliance.tolist(), self.frame_load.tolist())]
            rotation = rotation_from_rpy(*tool[3:])
        return PlantOutput(self.t, self.k, self.k * self.dt_ns, reading, velocity, list(applied), saturated, tool,
                           list(x),
                           fint, math.sqrt(sum(f * f for f in fint)), [f"{f.drive}:{f.kind}" for f in faults],
                           self.stopped, tuple(rotation.ravel().tolist()))

    def output(self) -> PlantOutput:
        """The outputs of the last step (or of the initial state)."""
        return self._last


class _CompiledStrutStep:
    """StrutPlant.step of a strut machine without faults or compliance, compiled
    (strut_step.py): the plant's state copied into arrays around two kernel calls.
    ``step`` returns None where the interpreted step must be taken (a command that is
    not n finite numbers, an end stop, a strut of zero length, a singular mass matrix):
    nothing has changed then."""

    def __init__(self, plant: StrutPlant):
        n, p = plant.n, plant.params
        self.plant = plant
        md, kf, inertia, mass, g = plant.dynamics.step_arguments()
        self.model = tuple(np.ascontiguousarray(a, dtype=float) for a in (md, kf, inertia)) + (
            float(mass), np.ascontiguousarray(g, dtype=float))
        self.bars = np.asarray(plant.machine.bars, dtype=float)
        self.h, self.substeps, self.limit = p.dt_s / p.substeps, int(p.substeps), float(p.force_limit_n)
        self.lower = np.array(plant.machine.joint_lower, dtype=float)
        self.upper = np.array(plant.machine.joint_upper, dtype=float)
        self.scale = np.ascontiguousarray(plant._reading_scale, dtype=float)
        self.cmd, self.applied, self.saturated, self.q = np.empty(n), np.empty(n), np.zeros(n, dtype=bool), np.empty(n)
        self.reading, self.velocity = np.empty(n), np.empty(n)

    def step(self, forces) -> PlantOutput | None:
        plant, cmd = self.plant, self.cmd
        if not take_commands(cmd, forces):
            return None                              # refused by the interpreted step, naming it, nothing changed
        plant._apply_schedules()
        # new arrays each step, as the interpreted step makes them (the kernel moves them in place)
        position = np.array(plant.p, dtype=float)
        rotation = np.array(plant.rotation, dtype=float).reshape(9)
        twist = np.array(plant.twist, dtype=float)
        load = np.ascontiguousarray(plant.load, dtype=float)
        try:
            code = strut_dynamics_step(cmd, self.limit, position, rotation, twist, load, self.bars, *self.model,
                                       self.h, self.substeps, self.lower, self.upper, self.applied, self.saturated,
                                       self.q)
        except np.linalg.LinAlgError:                # a singular mass matrix: the interpreted step names it
            return None
        if code != STEP_OK:
            return None
        plant.p, plant.rotation, plant.twist = position, rotation.reshape(3, 3), twist
        plant.t += plant.params.dt_s
        plant.k += 1
        enc = plant.encoders
        resolution, offsets, screw_errors, wavenumber = enc.kernel_arguments()
        strut_outputs(self.q, self.scale, resolution, offsets, screw_errors, wavenumber, enc.noise(plant.n),
                      enc.last_array(), enc.dt_s, self.reading, self.velocity)
        reading = enc.keep(self.reading)
        x, applied = plant.x, self.applied.tolist()       # (the interpreted step's: strut_step.py)
        fint = internal_force(plant.machine.jacobian(x), applied).tolist() if plant.n > 6 else [0.0] * plant.n
        plant._last = PlantOutput(plant.t, plant.k, plant.k * plant.dt_ns, reading, self.velocity.tolist(), applied,
                                  self.saturated.tolist(), list(x), list(x), fint, math.sqrt(sum(f * f for f in fint)),
                                  [], plant.stopped, tuple(rotation.tolist()))
        return plant._last
