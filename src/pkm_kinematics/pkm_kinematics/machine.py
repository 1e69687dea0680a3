"""The public interface of a machine model, as ``typing.Protocol``s: what the plant,
the controller, the metrology, the analyses and the panel may use of a machine, and
nothing else (no private attribute is read across modules). A machine is a platform
joined to the base by bars (../shared/MACHINE_MODEL.md).

- :class:`ParallelMachine`: every machine model (``RailMachine``, planar or
  translating; ``StrutMachine``, a hexapod; ``ParallelogramMachine``, MoM3's imperfect
  Delta, a plant's model): its task space, limits, kinematics, Jacobians and their
  condition numbers.
- :class:`ControlledMachine`: a machine the controller and the dynamic model drive:
  also the velocity terms (J, Jdot v) and each bar's two joints (the plant's
  markers). Every machine but the plant-only ParallelogramMachine.
- :class:`RailActuated`: the carriages on rails of a ``RailMachine`` (``bars`` as
  the kernels of ``bars`` take them, the rails' origins and directions, the task
  columns of the compiled velocity terms).
- :class:`SpatialMachine`: a 6-DOF machine's weighting of rotations against
  translations (``characteristic_length_m``).

tests/kinematics/test_machine_protocol.py checks every machine file of
config/machines against the Protocols its class claims.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from .task_space import TaskSpace


@dataclass
class ForwardKinematicsResult:
    """Outcome of an iterative forward kinematic solve.

    ``pose`` is NaN when ``converged`` is False, so a failed solve can never be used
    as a pose by mistake; ``reason`` says why it failed.
    """

    pose: np.ndarray
    converged: bool
    iterations: int
    residual_m: float
    reason: str = ""


@runtime_checkable
class ParallelMachine(Protocol):
    name: str
    description: str
    n_legs: int
    task_dof: int            # D of MoM3 §3: the coordinates the machine controls
    spatiality: int          # O of MoM3 §3: the dimension of the space its platform moves in
    task_space: TaskSpace    # the task coordinates' names and G-code words (task_space.py)
    leg_names: list
    joint_lower: np.ndarray
    joint_upper: np.ndarray
    workspace: dict

    @property
    def home(self) -> np.ndarray:
        """The machine's home in task coordinates (a pose or a position)."""

    def inverse_kinematics(self, x, check_limits: bool = True) -> np.ndarray: ...

    def inverse_kinematics_batch(self, xs) -> tuple[np.ndarray, np.ndarray]: ...

    def within_joint_limits(self, q) -> np.ndarray: ...

    def check_joint_limits(self, q) -> None:
        """Raise JointLimitError naming the first drive of ``q`` outside its limits."""

    def forward_kinematics_floats(self, q, guess=None) -> tuple[float, ...]: ...

    def jacobian(self, x, q=None) -> np.ndarray: ...

    def jacobian_batch(self, xs) -> np.ndarray: ...

    def task_jacobian_batch(self, xs) -> np.ndarray:
        """q' = J x' for the task coordinates' rates (the twist's, but for a hexapod's
        roll-pitch-yaw angles)."""

    def condition_number(self, x) -> float: ...

    def condition_number_batch(self, xs) -> np.ndarray: ...

    def rows_condition(self, jac) -> float:
        """The condition number of given rows of J_m (a sub-machine's: the drives still
        active), as ``condition_number`` measures it; inf when they do not span the
        task."""

    def workspace_grid(self, *args, **kwargs) -> np.ndarray: ...


@runtime_checkable
class ControlledMachine(ParallelMachine, Protocol):
    def velocity_terms(self, x, xdot) -> tuple:
        """(q, J, q', Jdot x') at ``x`` moving at ``xdot`` (the controller's feed-forward)."""

    def jacobian_derivative(self, x, xdot, q=None) -> np.ndarray: ...

    def leg_joints(self, x, q=None) -> tuple[np.ndarray, np.ndarray]:
        """Each bar's two joints (base or carriage side, platform side) at ``x``."""


@runtime_checkable
class RailActuated(ControlledMachine, Protocol):
    bars: np.ndarray          # the model: a row per bar (``bars.bar_rows``)
    twist_columns: np.ndarray  # the task coordinates' columns of the twist (the compiled velocity terms)

    @property
    def rail_origins(self) -> np.ndarray: ...

    @property
    def rail_directions(self) -> np.ndarray: ...

    def forward_kinematics_batch(self, q, *args, **kwargs): ...

    def velocity_terms_arrays(self, x, xdot) -> tuple: ...

    def raise_velocity_terms_error(self, code: int, leg: int, x) -> None: ...


@runtime_checkable
class SpatialMachine(ControlledMachine, Protocol):
    characteristic_length_m: float   # rotations against translations in cond(J_m) (struts.weighted_condition)


__all__ = ["ControlledMachine", "ParallelMachine", "RailActuated", "SpatialMachine"]
