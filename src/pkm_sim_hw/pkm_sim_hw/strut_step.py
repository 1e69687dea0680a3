"""A strut plant's step compiled (issue 45): what ``StrutPlant.step`` does for a strut
machine with no fault configured, no stop and no compliance, in two calls: the drives'
saturation (``drives.saturated_force``), the substeps of the semi-implicit rule on SE(3)
(``rigid_body.strut_step_kernel``), the strut lengths there
(``bars.inverse_kinematics_into``) and the end stops; then the encoders' reading of
each strut's measured length (``drives.encoder_reading``: screw error, offset, noise
drawn by the caller, resolution; the velocity by backward difference). The task
coordinates of the pose are left to the caller (``StrutPlant.x``): their pitch takes
``math.hypot``, which CPython computes with its own algorithm, not libm's (they differ
in the last bit for ~0.5 % of arguments), so a compiled ``rpy_kernel`` would not be the
interpreted step's. The interpreted step calls the same functions (their
``py_func``), so each formula is written once
(tests/sim_hw/test_strut_plant.py runs both). Anything else (a non-finite command, an
end stop, a strut of zero length, a singular mass matrix) returns its code with the
state untouched, and the caller takes the interpreted path, which names it."""

from __future__ import annotations

from pkm_kinematics.bars import inverse_kinematics_into
from pkm_kinematics.jit import direct_call, kernel
from pkm_kinematics.rigid_body import strut_step_kernel

from .drives import encoder_reading, saturated_forces
from .rail_step import STEP_NOT_TAKEN, STEP_OK

__all__ = ["STEP_NOT_TAKEN", "STEP_OK", "strut_dynamics_step", "strut_dynamics_step_kernel", "strut_outputs",
           "strut_outputs_kernel"]


@kernel("(float64[::1], float64, float64[::1], float64[::1], float64[::1], float64[::1], float64[:, :], "
        "float64[::1], float64[::1], float64[::1], float64, float64[::1], float64, int64, float64[::1], "
        "float64[::1], float64[::1], boolean[::1], float64[::1])")
def strut_dynamics_step_kernel(commanded, limit, position, rotation, twist, load, bars, md, kf, inertia, mass, g,
                               h, substeps, lower, upper, applied, saturated, q):
    """The step's dynamics (module doc): the pose (``position`` (3), ``rotation`` (9,
    row-major)) and ``twist`` (6) moved on in place; into ``applied``, ``saturated`` and
    the strut lengths ``q``. Returns STEP_OK, or STEP_NOT_TAKEN with the state untouched."""
    n = commanded.shape[0]
    if not saturated_forces(commanded, limit, applied, saturated):
        return STEP_NOT_TAKEN
    ok, p, r, t = strut_step_kernel(bars, position, rotation, twist, applied, load, md, kf, inertia, mass, g, h,
                                    substeps)
    if not ok:
        return STEP_NOT_TAKEN
    inverse_kinematics_into(bars, p, r, q)
    for i in range(n):                                  # the end stops
        if not lower[i] <= q[i] <= upper[i]:
            return STEP_NOT_TAKEN
    position[:] = p
    rotation[:] = r
    twist[:] = t
    return STEP_OK


@kernel("(float64[::1], float64[::1], float64, float64[::1], float64[::1], float64, float64[::1], float64[::1], "
        "float64, float64[::1], float64[::1])")
def strut_outputs_kernel(q, scale, resolution, offsets, screw_errors, wavenumber, noise, last_reading, dt_s,
                         reading, velocity):
    """The step's encoder outputs (module doc) into ``reading`` and ``velocity``: strut
    k reads ``scale[k] q[k]`` (1 / (1 + its length error)); ``offsets``,
    ``screw_errors``, ``noise`` (this step's, the standard normals times the noise's
    std) empty or one per strut; ``last_reading`` the previous reading."""
    n = q.shape[0]
    for i in range(n):                                  # drives.Encoders.read
        reading[i] = encoder_reading(q[i] * scale[i], screw_errors[i] if screw_errors.shape[0] else 0.0,
                                     wavenumber, offsets[i] if offsets.shape[0] else 0.0,
                                     noise[i] if noise.shape[0] else 0.0, resolution)
        velocity[i] = (reading[i] - last_reading[i]) / dt_s


strut_dynamics_step = direct_call(strut_dynamics_step_kernel)
strut_outputs = direct_call(strut_outputs_kernel)
