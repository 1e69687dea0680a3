"""A rail plant's step compiled whole (issue 45): what ``Plant.step`` does for a rail
machine integrated semi-implicitly with no fault configured, no stop and no bars of an
imperfect Delta, in one call: the drives' saturation (``drives.applied_forces``), the
substeps and the velocity terms at the state reached
(``dynamics.semi_implicit_step_kernel``), the end stops, the encoders' reading
(``drives.encoder_reading``: screw error, offset, noise drawn by the caller,
resolution; the velocity by backward difference), the internal force
(``distribution.internal_force_kernel``) and the tool's deflection
(``structure.deflected``). The interpreted step calls the same functions (their
``py_func``), so each formula is written once (tests/sim_hw/test_plant.py and
test_homing.py run both on the shipped rail machines). Anything
else (a non-finite command, an end stop, a pose the kinematics refuses, a singular
mass matrix) returns its code with the state untouched, and the caller takes the
interpreted path, which names it."""

from __future__ import annotations

import math

from pkm_kinematics import bars as B
from pkm_kinematics.distribution import internal_force_kernel
from pkm_kinematics.dynamics import semi_implicit_step_kernel
from pkm_kinematics.jit import direct_call, kernel

from .drives import encoder_reading, saturated_forces
from .structure import deflected

STEP_OK, STEP_NOT_TAKEN = 0, 1


@kernel("(float64[::1], float64, float64[::1], float64[::1], float64, int64, float64[:, :], int64[:], "
        "float64[:], float64[:], float64[:], float64, float64, float64, float64, float64, float64, "
        "float64[::1], float64[::1], float64[::1], boolean[::1], float64[::1], float64[:, ::1], float64[::1])")
def rail_dynamics_step_kernel(commanded, limit, state, load, h, substeps, bars, columns,
                              md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2, lower, upper,
                              applied, saturated, q, rows, internal):
    """The step's dynamics (module doc): ``state`` = (x, v) (6) moved on; into
    ``applied``, ``saturated``, the drive positions ``q``, J_m ``rows`` and the
    applied forces' null-space part, ``internal`` (zero for n = 3). Returns STEP_OK,
    or STEP_NOT_TAKEN with the state untouched."""
    n = commanded.shape[0]
    if not saturated_forces(commanded, limit, applied, saturated):
        return STEP_NOT_TAKEN
    x0, x1, x2, v0, v1, v2, q_end, rows_end, _, _, code, _ = semi_implicit_step_kernel(
        bars, columns, state[0], state[1], state[2], state[3], state[4], state[5], applied,
        load[0], load[1], load[2], h, substeps, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2)
    if code != B.VT_OK:
        return STEP_NOT_TAKEN
    for i in range(n):                                  # the end stops
        if not lower[i] <= q_end[i] <= upper[i]:
            return STEP_NOT_TAKEN
    if n > 3:
        part, ok = internal_force_kernel(rows_end, applied)
        if not ok:
            return STEP_NOT_TAKEN
        internal[:] = part
    else:
        internal[:] = 0.0
    q[:] = q_end
    rows[:, :] = rows_end
    state[0], state[1], state[2], state[3], state[4], state[5] = x0, x1, x2, v0, v1, v2
    return STEP_OK


@kernel("(float64[::1], float64[::1], float64, float64[::1], float64[::1], float64, float64[::1], "
        "float64[::1], float64, float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], "
        "float64[::1], float64[::1], float64[::1])")
def rail_outputs_kernel(q, internal, resolution, offsets, screw_errors, wavenumber, noise, last_reading,
                        dt_s, state, load, frame_load, compliance, frame_compliance, reading, velocity, tool):
    """The step's outputs (module doc) into ``reading``, ``velocity``, ``tool``:
    ``offsets``, ``screw_errors``, ``noise`` (this step's, the standard normals times
    the noise's std) empty or one per drive; ``last_reading`` the previous reading.
    Returns |internal|."""
    n = q.shape[0]
    for i in range(n):                                  # drives.Encoders.read
        reading[i] = encoder_reading(q[i], screw_errors[i] if screw_errors.shape[0] else 0.0, wavenumber,
                                     offsets[i] if offsets.shape[0] else 0.0,
                                     noise[i] if noise.shape[0] else 0.0, resolution)
        velocity[i] = (reading[i] - last_reading[i]) / dt_s
    norm = 0.0
    for i in range(n):
        norm += internal[i] * internal[i]
    for j in range(3):
        tool[j] = deflected(state[j], compliance[j], load[j], frame_compliance[j], frame_load[j])
    return math.sqrt(norm)


rail_dynamics_step = direct_call(rail_dynamics_step_kernel)
rail_outputs = direct_call(rail_outputs_kernel)
