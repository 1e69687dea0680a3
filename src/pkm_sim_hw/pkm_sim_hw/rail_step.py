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


# rail_step_kernel's packed arguments: its inputs (x, v, the load, the frame's load) ...
IN_X, IN_V, IN_LOAD, IN_FRAME_LOAD, IN_SIZE = 0, 3, 6, 9, 12
# ... its constants, then md, k, dg, the end stops' lower and upper (n each) ...
K_LIMIT, K_H, K_SUBSTEPS, K_MASS, K_COMPLIANCE, K_FRAME_COMPLIANCE, K_DRIVES = 0, 1, 2, 3, 9, 12, 15
# ... the encoders' (resolution, screw wavenumber, dt), and its outputs: x, v, the tool, then
# the applied forces, q, the internal force, the reading and the velocity (n each)
E_RESOLUTION, E_WAVENUMBER, E_DT = 0, 1, 2
OUT_X, OUT_V, OUT_TOOL, OUT_DRIVES = 0, 3, 6, 9


@kernel("(float64[::1], float64[::1], float64[::1], float64[:, :], int64[:], float64[::1], float64[::1], "
        "float64[::1], float64[::1], float64[::1], float64[::1], float64[:, ::1], boolean[::1])")
def rail_step_kernel(commanded, inputs, constants, bars, columns, encoder, offsets, screw_errors, noise,
                     last_reading, out, rows, saturated):
    """:func:`rail_dynamics_step_kernel` then :func:`rail_outputs_kernel` in one call,
    their arguments packed (the module's IN_, K_, E_ and OUT_ indices): fewer to
    convert per step. Returns (STEP_OK or STEP_NOT_TAKEN, |internal|)."""
    n = commanded.shape[0]
    c = constants
    drives = c[K_DRIVES:]
    md, k, dg, lower, upper = drives[:n], drives[n:2 * n], drives[2 * n:3 * n], drives[3 * n:4 * n], drives[4 * n:]
    state = out[OUT_X:OUT_X + 6]
    state[:] = inputs[IN_X:IN_X + 6]
    load, frame_load = inputs[IN_LOAD:IN_LOAD + 3], inputs[IN_FRAME_LOAD:IN_FRAME_LOAD + 3]
    outs = out[OUT_DRIVES:]
    applied, q, internal = outs[:n], outs[n:2 * n], outs[2 * n:3 * n]
    reading, velocity = outs[3 * n:4 * n], outs[4 * n:]
    code = rail_dynamics_step_kernel(commanded, c[K_LIMIT], state, load, c[K_H], int(c[K_SUBSTEPS]), bars, columns,
                                     md, k, dg, c[K_MASS], c[K_MASS + 1], c[K_MASS + 2], c[K_MASS + 3], c[K_MASS + 4],
                                     c[K_MASS + 5], lower, upper, applied, saturated, q, rows, internal)
    if code != STEP_OK:
        return code, 0.0
    norm = rail_outputs_kernel(q, internal, encoder[E_RESOLUTION], offsets, screw_errors, encoder[E_WAVENUMBER], noise,
                               last_reading, encoder[E_DT], state, load, frame_load,
                               c[K_COMPLIANCE:K_COMPLIANCE + 3], c[K_FRAME_COMPLIANCE:K_FRAME_COMPLIANCE + 3],
                               reading, velocity, out[OUT_TOOL:OUT_TOOL + 3])
    return STEP_OK, norm


rail_step = direct_call(rail_step_kernel)       # _CompiledStep makes each argument with its declared type
