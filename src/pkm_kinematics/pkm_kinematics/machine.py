"""The one public interface of a machine model (``ParallelMachine``): what the plant,
the controller, the metrology, the analyses and the panel may use of a
``RailMachine`` (planar or translating), a ``ParallelogramMachine`` or a
``StrutMachine``, and nothing else (no private
attribute is read across modules). A machine is a platform joined to the base by
bars (../shared/MACHINE_MODEL.md): ``bars`` holds them as the kernels of ``bars``
take them (a row per bar), ``leg_joints`` gives each bar's two joints,
``rail_origins`` / ``rail_directions`` the actuated rails the carriages ride on.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from .task_space import TaskSpace


@runtime_checkable
class ParallelMachine(Protocol):
    name: str
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

    @property
    def rail_origins(self) -> np.ndarray: ...

    @property
    def rail_directions(self) -> np.ndarray: ...

    bars: np.ndarray          # the model: a row per bar (``bars.bar_rows``)

    def leg_joints(self, x, q=None) -> tuple[np.ndarray, np.ndarray]: ...

    def inverse_kinematics(self, x, check_limits: bool = True) -> np.ndarray: ...

    def inverse_kinematics_batch(self, xs) -> tuple[np.ndarray, np.ndarray]: ...

    def within_joint_limits(self, q) -> np.ndarray: ...

    def check_joint_limits(self, q) -> None:
        """Raise JointLimitError naming the first drive of ``q`` outside its limits."""

    def forward_kinematics_floats(self, q, guess=None) -> tuple[float, float, float]: ...

    def forward_kinematics_batch(self, q, *args, **kwargs): ...

    def jacobian(self, x, q=None) -> np.ndarray: ...

    def jacobian_batch(self, xs) -> np.ndarray: ...

    def task_jacobian_batch(self, xs) -> np.ndarray:
        """q' = J x' for the task coordinates' rates (the twist's, but for a hexapod's
        roll-pitch-yaw angles)."""

    def condition_number_batch(self, xs) -> np.ndarray: ...

    def jacobian_derivative(self, x, xdot, q=None) -> np.ndarray: ...

    def velocity_terms(self, x, xdot) -> tuple: ...

    def velocity_terms_arrays(self, x, xdot) -> tuple: ...

    def raise_velocity_terms_error(self, code: int, leg: int, x) -> None: ...

    def condition_number(self, x) -> float: ...


__all__ = ["ParallelMachine"]
