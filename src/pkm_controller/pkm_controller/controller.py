"""The redundant-actuation controller (pure core, no rclpy): strategies, force
distribution and the safety supervisor, one ``update`` per control cycle.

``ControllerCore.update(stamp_ns, q, qdot, applied, struts=None, metrology_pose=None)``
takes one drive state (its stamp in integer nanoseconds, as it travels) (encoder positions and velocities, the forces the drives
report applying) and, for the metrology strategies, the Gough strut readings or the
Gough pose of the same instant, and returns the drive forces to apply until the next
state. A node splits it in two: ``prepare(stamp_ns, q, qdot, applied)`` as soon as the
drive state arrives (FK, supervision, reference, l_des, J_h, A(x), H(x, v)) and
``complete(struts, metrology_pose)`` when the metrology of that instant does, so the
readings wait only for the feedback, the law and the distribution. Strategies
(the registry ``pkm_controller.strategies``):

1. ``joint_pid``               independent PID per drive on IK setpoints (ARCHI §4.1), with
                               acceleration feed-forward of the mass each drive sees
2. ``decentralized_projected`` the same PIDs, forces projected n = J (J^T J)^-1 J^T n_d
                               and the integral kept in range(J) (Sliding Star eq. 6-8, Fig. 8)
   ``decentralized_integral_projected`` the same PIDs, only the integral component
                               projected (Sliding Star Fig. 9, the lab model's variant)
3. ``cartesian_pid``           PID on the pose from forward kinematics of the encoders (+ the
                               same diagonal-mass feed-forward), F distributed (Sliding Star
                               eq. 9, ARCHI §4.2)
4. ``computed_torque``         F = A(x)(a_d + Kd edot + Kp e + Ki int e) + H(x, v) (ARCHI §4.2-4.4)
5. ``sensor_space``            PI + velocity feed-forward on the Gough strut lengths through
                               J_t at the estimated real pose (MoM3 §6.4)
6. ``measured_space``          the same on the Gough DKM pose (MoM3 §6.3)

Cartesian wrenches go to the drives through a distribution of pkm_kinematics
(pseudo_inverse, inf_norm, p_norm, two_arm; optional prestress). Every cycle the
supervisor checks the inputs (NaN, length), the joint and workspace limits, the
singularity margin of the active drives, the following error, force saturation and
the drives' reported forces against the commands (a failed drive). A trip puts the
controller in its safe state: zero forces, ``stopped`` with the reason and its
``TripCause`` (pkm_common.causes); the node adds the brakes (estop). A frozen or
slipping encoder is seen from the motion the reference asks for (encoder_check), and
a plant that braked on its own (``plant_stopped``, from the drives' status word) is
reported with the plant's cause, not as the drives' failure it looks like. On a redundant machine a drive that stops producing force is
dropped and the machine continues on the remaining ones when that sub-machine is
far enough from singular.
"""

from __future__ import annotations

import numpy as np

from pkm_common.causes import TripCause
from pkm_kinematics.analysis import task_box
from pkm_kinematics.config import MachineConfig
from pkm_kinematics.compensation import compensation_of
from pkm_kinematics.dynamics import dynamic_model
from pkm_kinematics.errors import KinematicsError
from pkm_kinematics.task_space import PLANAR

from .commands import cartesian_failure, distribute_wrench, joint_command, kernels_for
from .compiled_prepare import CompiledPrepare
from .config import ControllerConfig, check_runtime_names
from .cycle import AnswerLog, Cycle, CycleRecord
from .encoder_check import EncoderChecks
from .laws import LIMITS_OK, clamp_forces_kernel, tool_pose_floats
from .pose_estimation import PoseEstimator, sensor_feedback
from .reference import Reference
from .status import controller_status
from .strategies import Feedback, strategy
from .supervisor import Supervisor
from .tracking import Approach, ReferenceTracker
from .tuning import MachineTuning, holding_integral, zero_integral

FUSE_SENSOR_SPACE = True    # False: the feedback and the command in two calls (the reference of a test)
ANSWERS_KEPT = 64           # answers kept for held setpoints (the sync counter trips after a few)


class ControllerCore:
    """One controller for one machine. ``update`` per cycle; ``set_trajectory`` to move."""

    def __init__(self, machine: MachineConfig, config: ControllerConfig | None = None):
        self.machine = machine
        self.config = config or ControllerConfig()
        self.model = machine.model
        self.compensation = compensation_of(machine)     # the machine file's drive tables, or None
        # the task coordinates (pkm_kinematics.task_space): planar and position machines
        # run the compiled 3-DOF kernels of laws.py; a spatial one (x, y, z, a, b, c)
        # feeds back twists and the rotation vector (laws.spatial_command_kernel)
        self.space = self.model.task_space
        self.dof = self.space.dof
        self.planar = self.space is PLANAR
        self.n = self.model.n_legs
        self.names = list(self.model.leg_names)
        if machine.dynamics is None:
            raise ValueError(f"machine {machine.name!r}: the controller needs a 'dynamics' section "
                             f"(model terms and gain scaling)")
        self.dynamics = dynamic_model(machine)
        # cond(J_m) of the active drives: the 3-DOF closed form, or the machine's own
        # (a spatial J_m's rotation columns weighted by the platform's size)
        self._condition = self.model.rows_condition
        self.tuning = MachineTuning(machine, self.dynamics)
        self.tuning.check(self.config)
        self.strategy = strategy(self.config.strategy)
        self.metrology = sensor_feedback(machine, self.strategy, self.config)     # the Gough's, or None
        # per drive (lower, upper) and per task axis (lower, upper): laws.limits_kernel
        self.joint_box = np.column_stack([self.model.joint_lower, self.model.joint_upper]).astype(float)
        # the translation box, and a spatial machine's angles within their ranges about home
        self.workspace_box = np.array(task_box(self.model, self.config.workspace_margin_m,
                                               self.config.workspace_margin_rad), dtype=float)
        self.kernels = kernels_for(self.model)          # the task space's compiled kernels (commands.py)
        self.supervisor = Supervisor(self.config, self.names, self.dof, self.space, self.joint_box,
                                     self.workspace_box, self._condition, self.model)
        self.estimator = PoseEstimator(self.model, self.config, self.strategy.feedback, self.metrology)
        self._apply_config()
        self.reset()

    # ---------------------------------------------------------------- set-up
    def _apply_config(self) -> None:
        """What the strategy, the gains and the distribution make of ``self.config``."""
        c = self.config
        self.supervisor.config = self.estimator.config = c
        self.strategy = strategy(c.strategy)
        # sensor_space on a 3-axis machine: the feedback and the command in one compiled call
        self.fused_struts = FUSE_SENSOR_SPACE and self.strategy.feedback == Feedback.STRUTS \
            and not self.strategy.joint_space and hasattr(self.kernels, "sensor_space")
        self.tuned = self.tuning.scaled(c)
        # the kernels' packed inputs of this configuration (commands.CommandSetup)
        self.setup = self.kernels.setup(c, self.tuned, (self.joint_box, self.workspace_box), self.n)

    def change_settings(self, changes: dict) -> dict:
        """Change the strategy, the distribution or the gains of a running controller
        (an operator's panel; Sliding Star Fig. 12: regulator gains, projection ON/OFF),
        between two cycles: only ``RUNTIME_SETTINGS``, validated and taken over as
        ``MachineTuning.takeover`` says. Returns the settings changed; ValueError
        (naming the field and its range), nothing changed."""
        check_runtime_names(changes)
        if self.stopped:
            raise ValueError(f"settings refused: the controller is stopped ({self.stop_reason})")
        self.config, integral = self.tuning.takeover(self.config, changes, self.estimator.pose,
                                                     self.supervisor.active)
        self._apply_config()
        self.compiled = CompiledPrepare.of(self)
        if integral is not None:
            self.integral = integral
        return dict(changes)

    def reset(self) -> None:
        """Back to the state before the first cycle (lifecycle cleanup / re-activate)."""
        c = self.config
        self.tracker = ReferenceTracker(self.space, c.start_tolerance_m, c.start_tolerance_rad, self.kernels.twists,
                                        Approach.of(c))
        self.estimator.reset()
        self.last_stamp_ns: int | None = None   # the stamp of the last state (the answers' key)
        self.last_time_s: float | None = None   # the same in seconds (the reference's time)
        self._cycle: Cycle | None = None        # prepared, waiting for complete()
        self.supervisor.reset()
        self.integral = zero_integral(self.strategy.law, self.n, self.dof)
        self.encoder_checks = EncoderChecks(self.model, self.names, c, self.strategy.uses_metrology)
        self.last_command = [0.0] * self.n
        # the last answers by the stamp (ns) of their state: a realtime plant may apply
        # one of them again (a held setpoint) and report the forces of that one
        self.answers = AnswerLog(ANSWERS_KEPT)
        self.cycles = 0
        self.peak_force_n = 0.0
        self.max_error_m = 0.0
        zero = (0.0,) * self.dof           # a 6-DOF machine's status before its first cycle (an E-stop then)
        self.record = CycleRecord(reference=zero, measured=zero, error=zero, forces=(0.0,) * self.n)
        if self.metrology is not None:
            self.metrology.reset()
        # a usual cycle's prepare in one compiled call, where the configuration has it
        self.compiled = CompiledPrepare.of(self)

    # ------------------------------------------------- the supervisor's state
    @property
    def stopped(self) -> bool:
        return self.supervisor.stopped

    @property
    def stop_reason(self) -> str:
        return self.supervisor.stop_reason

    @property
    def stop_cause(self) -> TripCause:
        return self.supervisor.stop_cause

    # ------------------------------------------------------------ trajectory
    @property
    def mode(self) -> str:
        return "stopped" if self.stopped else self.tracker.mode(self.last_time_s)

    @property
    def reference(self) -> Reference | None:
        return self.tracker.reference

    @property
    def feed(self):
        """The trajectory's time under the feed override (feed.FeedClock)."""
        return self.tracker.feed

    def set_trajectory(self, reference: Reference, now_s: float | None = None) -> dict | None:
        """Start ``reference`` at ``now_s`` (the time of the next state; None: at the next
        cycle). Refused (ValueError, nothing moves) when stopped, while another
        trajectory runs, or when it does not start at the current reference; returns
        the approach move it starts with (tracking.ReferenceTracker.starting), if any."""
        if self.stopped:
            raise ValueError(f"trajectory refused: the controller is stopped ({self.stop_reason})")
        if self.mode == "tracking":
            raise ValueError("trajectory refused: another trajectory is running")
        return self.tracker.set_trajectory(reference, self.last_time_s if now_s is None else now_s)

    # ----------------------------------------------------------------- safety
    def trip(self, reason: str, cause: TripCause) -> list:
        """Safe state: zero forces from now on; the first reason and cause are kept
        and reported."""
        self.supervisor.trip(reason, cause)
        self.last_command = [0.0] * self.n
        self.record.forces = tuple(self.last_command)
        return list(self.last_command)

    def plant_stopped(self, cause: TripCause) -> list:
        """The plant braked on its own (the drives' status word, pkm_common.causes): the
        stop is the plant's, with the plant's cause."""
        return self.trip(f"the plant stopped ({cause})", cause)

    def _check_limits(self, q, active_rows, measured, error) -> tuple[tuple | None, float]:
        """(the Trip or None, the translation error) of the task space's limits kernel."""
        code, index, value = self.kernels.limits(q, active_rows, measured, error, self.setup)
        return (None, value) if code == LIMITS_OK else (self.supervisor.limit_trip(code, index, value), value)

    # ------------------------------------------------------------------ cycle
    def update(self, stamp_ns: int, q, qdot, applied=None, struts=None, metrology_pose=None,
               held: int | None = None) -> list:
        """One control cycle on the state stamped ``stamp_ns`` (int ns); returns the
        drive forces (N) for the next period. The same as ``prepare`` on the drive
        state, then ``complete`` on the metrology."""
        if not self.prepare(stamp_ns, q, qdot, applied, held):
            return list(self.last_command)
        return self.complete(struts, metrology_pose)

    def prepare(self, stamp_ns: int, q, qdot, applied=None, held: int | None = None) -> bool:
        """The first half of a cycle, on the drive state stamped ``stamp_ns`` (int ns, the
        key of its answer) alone: the input checks, the encoder FK, the drive
        supervision, J_m and the task velocity, the reference and what the strategy
        derives from them (l_des and J_h, A(x), H(x, v)), while the metrology of the
        same instant is on its way. False when the controller is (now) stopped:
        ``last_command`` (zeros) answers. ``held``: the stamp of the older command the
        plant applied again (causes.PlantStatus); the drive supervision compares the
        forces with that one, or skips the cycle when it does not know it."""
        if self.compiled is not None:
            self._cycle = self.compiled.prepare(stamp_ns, q, qdot, applied, held)
            if self._cycle is not None:
                return True
        sup = self.supervisor
        self._cycle = None
        if sup.stopped:
            self.trip(sup.stop_reason, sup.stop_cause)
            return False
        problem = sup.check_state(q, qdot, applied)
        if problem is not None:
            self.trip(*problem)
            return False
        if self.encoder_checks.pending is not None:     # the last cycle's readings, for the Gough to judge
            problem = self.encoder_checks.check_against_gough(sup.failed)
            if problem is not None:
                self.trip(*problem)
                return False
        q, qdot, q_array = list(q), list(qdot), np.array(q, dtype=float)
        if self.compensation is not None:      # the drives' tables (pkm_kinematics.compensation): true positions
            qdot = self.compensation.velocities(q_array, qdot).tolist()
            q_array = self.compensation.positions(q_array)
            q = q_array.tolist()
        t_s = stamp_ns * 1e-9
        dt = self.config.dt_s if self.last_time_s is None or t_s <= self.last_time_s else t_s - self.last_time_s
        first = self.last_time_s is None
        self.last_stamp_ns, self.last_time_s = stamp_ns, t_s
        try:
            pose, state = self.estimator.encoder_state(q_array, qdot, self.dynamics)
        except (KinematicsError, ValueError) as exc:
            self.trip(f"forward kinematics of the encoders: {exc}", TripCause.KINEMATICS)
            return False
        if first:       # until a cycle has a reference of its own, the machine is asked to stay where it is
            self.record.reference = self.record.measured = tuple(float(v) for v in pose)
        sup.forces_mismatched = False
        delay = self.config.actuation_delay_cycles      # drives that apply a command a cycle (or more) later
        if held is not None:
            commanded = self.answers.get(held)
        else:
            commanded = self.last_command if not delay else self.answers.before_last(delay)
        if applied is not None and len(applied) and not first and commanded is not None:
            problem = sup.check_drives(list(applied), commanded, self.estimator.pose)
            if problem is not None:
                self.trip(*problem)
                return False
        try:
            # J_m, v = J_m^+ qdot, and A(x), H(x, v) for the model-based strategies: one compiled call
            a_model, h_model, rows_a, v = state if state is not None else self.dynamics.measured_state(pose, qdot)
        except (KinematicsError, ValueError) as exc:
            self.trip(f"kinematics at the measured pose: {exc}", TripCause.KINEMATICS)
            return False
        active_rows = rows_a if len(sup.active) == self.n else rows_a[sup.active]
        self._cycle = c = Cycle(stamp_ns, t_s, dt, first, q, q_array, qdot, pose, rows_a, active_rows, v)
        c.a_model, c.h_model, c.applied, c.held = a_model, h_model, applied, held is not None
        return first or self._prepare_reference(c)

    def _prepare_reference(self, c: "Cycle") -> bool:
        """The reference of the cycle and what the strategy derives from it before the
        metrology arrives (sensor_space: l_des and J_h)."""
        sup = self.supervisor
        c.x_d, c.v_d, c.a_d = self.tracker.sample(c.t_s)
        if self.encoder_checks.encoders is not None:
            problem = self.encoder_checks.check_cycle(c, sup.forces_mismatched, sup.failed)
            if problem is not None:
                self._cycle = None
                self.trip(*problem)
                return False
        try:
            if self.strategy.feedback == Feedback.STRUTS:
                self.metrology.prepare(*tool_pose_floats(c.x_d, self.planar))
        except (KinematicsError, ValueError, np.linalg.LinAlgError) as exc:
            self._cycle = None
            self.trip(f"{self.strategy.name}: {exc}", TripCause.KINEMATICS)
            return False
        return True

    def complete(self, struts=None, metrology_pose=None) -> list:
        """The second half of the cycle ``prepare`` began: the feedback from the
        metrology (sensor_space: the strut lengths; measured_space: the Gough pose;
        ignored by the encoder strategies), the limits, the control law and the force
        distribution. Returns the drive forces (N) for the next period."""
        sup = self.supervisor
        c, self._cycle = self._cycle, None
        if sup.stopped:
            return self.trip(sup.stop_reason, sup.stop_cause)
        if c is None:
            raise RuntimeError("ControllerCore.complete: no cycle prepared (call prepare() first)")
        problem = sup.check_metrology(self.strategy.feedback, struts, metrology_pose)
        if problem is not None:
            return self.trip(*problem)
        if c.first:
            self._start(c.pose, struts, metrology_pose)
            if not self._prepare_reference(c):
                return list(self.last_command)
        try:
            if c.first:         # the PID laws start holding the load (a singular start pose trips here)
                self.integral = holding_integral(self.dynamics, self.model, c.pose, self.strategy.law,
                                                 self.config.integral_time_s, sup.active, c.active_rows)
            if self.fused_struts and not c.first:     # sensor_space, 3 axes: feedback to forces in one call
                measured, error, outcome = self.compiled.sensor_space(c, struts) if c.compiled else \
                    self.kernels.sensor_space(self, c, struts)
                if self.encoder_checks.gough_check is not None:
                    self.encoder_checks.keep_for_gough(c.q_array, measured, c.suspect)
                return self._cartesian_outcome(c, measured, error, outcome)
            measured, error = self.estimator.measure(c.pose, c.x_d, struts, metrology_pose)
            if not c.first and self.encoder_checks.gough_check is not None:
                self.encoder_checks.keep_for_gough(c.q_array, measured, c.suspect)   # judged in the next prepare
            if not self.strategy.joint_space:
                return self._cartesian_command(c, measured, error)
            problem, trans = self._check_limits(c.q_array, c.active_rows, measured, error)
            if problem:
                return self.trip(*problem)
            forces, self.integral = joint_command(self.model, self.kernels, self.tuned, self.config,
                                                  self.strategy.projection, sup.active, self.n, self.integral, c)
        except (KinematicsError, ValueError, np.linalg.LinAlgError) as exc:
            return self.trip(f"{self.config.strategy}: {exc}", TripCause.KINEMATICS)
        return self._finish(c, forces, trans, measured, error)

    def _start(self, pose, struts, metrology_pose) -> None:
        """First cycle: hold where the machine is (as the strategy measures it), then
        start a trajectory that arrived before the first state (refused: reported,
        the machine holds)."""
        refused = self.tracker.hold(self.estimator.hold_pose(self.strategy.feedback, pose, struts, metrology_pose),
                                    self.last_time_s)
        if refused is not None:
            self.supervisor.faults.append(refused)

    def _cartesian_command(self, c: "Cycle", measured, error) -> list:
        """The Cartesian strategies after the feedback: limits, integral, law (Sliding
        Star eq. 9; ARCHI §4.2-4.4; MoM3 §6.1), distribution and clamp in one compiled
        call (commands.py, by task space); the distributions it does not compile
        distribute the wrench it returns with numpy."""
        return self._cartesian_outcome(c, measured, error, self.kernels.cartesian(self, c, measured, error))

    def _cartesian_outcome(self, c: "Cycle", measured, error, outcome) -> list:
        """What a Cartesian command kernel returned (a commands.CartesianOutcome): the
        command accepted, the wrench distributed by numpy, or the trip it names."""
        code, index, value, self.integral, wrench, forces, distributed, saturated, peak = outcome
        if code == LIMITS_OK and distributed:
            return self._accept(c, forces, saturated, peak, value, measured, error)
        if code == LIMITS_OK:
            forces = distribute_wrench(self.config, self.dynamics, self.model, self.kernels.wrench_list(wrench),
                                       c.active_rows, c.pose, self.supervisor.active, self.n)
            return self._finish(c, forces, value, measured, error)
        return self.trip(*cartesian_failure(code, index, value, self.kernels.wrench_list(wrench), forces,
                                            self.config.strategy, self.supervisor))

    def _finish(self, c: "Cycle", forces, trans, measured, error) -> list:
        """Clamp the forces of the strategies computed in Python, then ``_accept``."""
        clamped, saturated, peak, finite = clamp_forces_kernel(np.array(forces, dtype=float),
                                                               self.config.force_limit_n)
        if not finite:
            return self.trip(f"{self.config.strategy}: non-finite drive forces {forces}", TripCause.KINEMATICS)
        return self._accept(c, clamped.tolist(), saturated, peak, trans, measured, error)

    def _accept(self, c: "Cycle", forces, saturated, peak, trans, measured, error) -> list:
        """The clamped command of the cycle: the saturation supervisor, the statistics,
        the record."""
        sup = self.supervisor
        if saturated or sup.saturated_since is not None:      # (else nothing to count or clear)
            problem = sup.check_saturation(c.t_s, saturated)
            if problem is not None:
                return self.trip(*problem)
        self.cycles += 1
        self.last_command = forces
        self.answers.keep(c.stamp_ns, forces)
        self.peak_force_n = max(self.peak_force_n, peak)
        self.max_error_m = max(self.max_error_m, trans)
        r = self.record
        r.time_s, r.reference, r.measured, r.error = c.t_s, tuple(c.x_d), tuple(measured), tuple(error)
        r.forces, r.saturated, r.rows = tuple(forces), saturated, c.rows
        return forces

    # ----------------------------------------------------------------- status
    def status(self) -> tuple[int, str, dict]:
        """(level 0 OK / 1 WARN / 2 ERROR, message, values) for controller/status."""
        return controller_status(self)
