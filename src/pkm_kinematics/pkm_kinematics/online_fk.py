"""On-line forward kinematics by integrating the differential kinematics (Sliding Star
§3.1: "the approach of differential kinematics being on-line integrated").

Instead of solving the closure equations for the pose every cycle (Newton's method,
``forward_kinematics_floats``), the pose is carried from cycle to cycle by the drive
increments: x_{k+1} = x_k + J_m^+ (q_{k+1} - q_k), with qdot = J_m xdot and J_m^+ its
least-squares inverse (a redundant machine's increments that no motion explains are
left out). No iteration; the price is a drift, which nothing in the increments can
see. ``order`` 1 (explicit Euler, J_m at x_k) errs by a term first order in the step:
on Sliding Star at 0.5 m/s and 1 kHz about 0.1 mm, not growing over repeated loops;
``order`` 2 (the midpoint rule, J_m at x_k + half the Euler step, two solves) by
about 0.1 um (``pkm-gallery sliding_star_online_fk``). The controller's
``fk_resync_cycles`` also bounds either with a Newton solution every so many cycles.
"""

from __future__ import annotations

import numpy as np

from .errors import FieldError
from .validation import finite_floats


def integrate_forward_kinematics(machine, pose, dq, order: int = 2) -> np.ndarray:
    """One step of the on-line forward kinematics of Sliding Star §3.1:
    x_{k+1} = x_k + J_m^+(x*) dq, ``dq`` the drive increments since the pose being
    carried (planar: (x, y, theta); translational: the position); x* = x_k (``order``
    1, explicit Euler) or x_k + J_m^+(x_k) dq / 2 (``order`` 2, the midpoint rule)."""
    if order not in (1, 2):
        raise FieldError("order", f"must be 1 or 2, got {order!r}")
    pose = np.asarray(finite_floats(pose, 3, "pose"))
    dq = np.asarray(finite_floats(dq, machine.n_legs, "dq"))
    step, *_ = np.linalg.lstsq(machine.jacobian(pose), dq, rcond=None)
    if order == 2:
        step, *_ = np.linalg.lstsq(machine.jacobian(pose + 0.5 * step), dq, rcond=None)
    return pose + step
