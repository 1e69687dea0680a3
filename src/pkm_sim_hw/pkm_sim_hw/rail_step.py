"""A rail plant's step compiled whole (issue 45): what ``Plant.step`` does for a rail
machine integrated semi-implicitly with no fault configured, no stop and no bars of an
imperfect Delta, in one call: the drives' saturation (``drives.applied_forces``), the
substeps and the velocity terms at the state reached
(``dynamics.semi_implicit_step_kernel``), the end stops, the encoders' reading
(``drives.Encoders.quantise`` and ``read``: screw error, offset, noise drawn by the
caller, resolution; the velocity by backward difference), the internal force
(``distribution.project_kernel``) and the tool's deflection (``Plant._output``). The
same floats as those functions: each is the formula they compute, in their order
(tests/sim_hw/test_plant.py and test_homing.py run both on the shipped rail machines). Anything
else (a non-finite command, an end stop, a pose the kinematics refuses, a singular
mass matrix) returns its code with the state untouched, and the caller takes the
interpreted path, which names it."""

from __future__ import annotations

import math

from pkm_kinematics import bars as B
from pkm_kinematics.distribution import project_kernel
from pkm_kinematics.dynamics import semi_implicit_step_kernel
from pkm_kinematics.jit import direct_call, kernel

STEP_OK, STEP_NOT_TAKEN = 0, 1


@kernel("(float64[::1], float64, float64[::1], float64[::1], float64, int64, float64[:, :], int64[:], "
        "float64[:], float64[:], float64[:], float64, float64, float64, float64, float64, float64, "
        "float64[::1], float64[::1], float64[::1], boolean[::1], float64[::1], float64[:, ::1], float64[::1])")
def rail_dynamics_step_kernel(commanded, limit, state, load, h, substeps, bars, columns,
                              md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2, lower, upper,
                              applied, saturated, q, rows, projected):
    """The step's dynamics (module doc): ``state`` = (x, v) (6) moved on; into
    ``applied``, ``saturated``, the drive positions ``q``, J_m ``rows`` and the part
    of the applied forces J_m carries, ``projected`` (n > 3). Returns STEP_OK, or
    STEP_NOT_TAKEN with the state untouched."""
    n = commanded.shape[0]
    total = 0.0
    for i in range(n):
        total += commanded[i]
    if not math.isfinite(total):
        return STEP_NOT_TAKEN
    for i in range(n):                                  # drives.applied_forces
        f = commanded[i]
        saturated[i] = abs(f) > limit
        applied[i] = max(-limit, min(limit, f))
    x0, x1, x2, v0, v1, v2, q_end, rows_end, _, _, code, _ = semi_implicit_step_kernel(
        bars, columns, state[0], state[1], state[2], state[3], state[4], state[5], applied,
        load[0], load[1], load[2], h, substeps, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2)
    if code != B.VT_OK:
        return STEP_NOT_TAKEN
    for i in range(n):                                  # the end stops
        if not lower[i] <= q_end[i] <= upper[i]:
            return STEP_NOT_TAKEN
    if n > 3:
        part, ok = project_kernel(rows_end, applied)
        if not ok:
            return STEP_NOT_TAKEN
        projected[:] = part
    q[:] = q_end
    rows[:, :] = rows_end
    state[0], state[1], state[2], state[3], state[4], state[5] = x0, x1, x2, v0, v1, v2
    return STEP_OK


@kernel("(float64[::1], float64[::1], float64[::1], float64, float64[::1], float64[::1], float64, float64[::1], "
        "float64[::1], float64, float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], "
        "float64[::1], float64[::1], float64[::1], float64[::1])")
def rail_outputs_kernel(q, applied, projected, resolution, offsets, screw_errors, wavenumber, noise, last_reading,
                        dt_s, state, load, frame_load, compliance, frame_compliance, reading, velocity, tool, fint):
    """The step's outputs (module doc) into ``reading``, ``velocity``, ``tool``,
    ``fint``: ``offsets``, ``screw_errors``, ``noise`` (this step's, the standard
    normals times the noise's std) empty or one per drive; ``last_reading`` the
    previous reading. Returns |fint|."""
    n = q.shape[0]
    for i in range(n):                                  # drives.Encoders.quantise, then read
        qi = q[i]
        if screw_errors.shape[0]:
            qi = qi + screw_errors[i] * math.sin(wavenumber * qi)
        if offsets.shape[0]:
            qi = qi + offsets[i]
        if noise.shape[0]:
            qi = qi + noise[i]
        if resolution > 0.0:
            qi = round(qi / resolution) * resolution
        reading[i] = qi
        velocity[i] = (qi - last_reading[i]) / dt_s
    norm = 0.0
    for i in range(n):                                  # distribution.internal_force_rows
        fint[i] = applied[i] - projected[i] if n > 3 else 0.0
        norm += fint[i] * fint[i]
    for j in range(3):                                  # Plant._output: the tool's deflection
        tool[j] = state[j] + compliance[j] * load[j] + frame_compliance[j] * frame_load[j]
    return math.sqrt(norm)


rail_dynamics_step = direct_call(rail_dynamics_step_kernel)
rail_outputs = direct_call(rail_outputs_kernel)
