"""Gough-platform metrology model: the sensor of Separation of Actuation and Measurement.

Pure core (no rclpy, no messages). MoM3 §4.2-4.3: a passive 6-strut Gough platform
measures the pose of the tool plate through six linear scales of 1 um resolution;
§6.3: the pose follows from the direct kinematic model (DKM_GP, Newton-Raphson).

Two geometries:

* the TRUE geometry measures: the nominal joint centres A_i, b_i of the machine file,
  each perturbed once by N(0, calibration_error_m) per axis (a mis-calibrated sensor;
  0 gives the nominal geometry);
* the NOMINAL geometry (the machine file) solves the DKM, as a real controller only
  knows its calibration.

Frames (docs/architecture.md, Conventions): the Gough base sits in the machine's world
frame at (p_wb, R_wb); the Gough plate sits in the tool frame at (p_tp, R_tp). So
T_base_plate = T_world_base^-1 T_world_tool T_tool_plate:
  R_bp = R_wb^T R_t R_tp,   p_bp = R_wb^T (p_t + R_t p_tp - p_wb)
and back: R_t = R_wb R_bp R_tp^T,  p_t = p_wb + R_wb p_bp - R_t p_tp.

This runs once per control cycle (1-2 kHz), so the per-call arithmetic is done on
Python floats: numpy costs ~1-2 us per operation on 3-vectors.
"""

from __future__ import annotations

import math

import numpy as np

from pkm_kinematics.config import GoughMetrologyConfig
from pkm_common.cdr_kernels import STAMP_OK, copy_stamp, read_doubles, read_stamp, write_doubles
from pkm_common.noise import NormalDraws
from pkm_common.poses import QUATERNION_NORM_TOL, pose_components
from pkm_kinematics.bars import COL_A, COL_B, FK_CONVERGED, STRUT, bar_rows, strut_lengths_kernel
from pkm_kinematics.errors import FieldError
from pkm_kinematics.gough import GoughDKMResult, GoughDKMSolver, GoughPlatform, dkm_solve_kernel
from pkm_kinematics.jit import direct_call, kernel
from pkm_kinematics.rotations import (mul3_kernel, mv3_kernel, rotation_quaternion_kernel,
                                      unit_quaternion_rotation_kernel)
from pkm_kinematics.validation import finite_floats

STRUT_NAMES = tuple(f'strut{i}' for i in range(1, 7))
MAX_RESOLUTION_M = 1e-3          # as the machine file's encoder_resolution
ROTATION_TOL = 1e-6              # |R^T R - I| allowed in a tool rotation
DKM_TOL_FRACTION = 1e-3          # DKM strut residual tolerance, as a fraction of the resolution


def _nonneg(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise FieldError(name, f'expected a number >= 0 m, got {value!r}') from None
    if not math.isfinite(v) or v < 0.0:
        raise FieldError(name, f'must be in [0, inf) m, got {value!r}')
    return v


def _t(r: tuple) -> tuple:
    """Transpose of a row-major 9-tuple."""
    return (r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8])


@kernel()
def rotation_defect_kernel(r) -> tuple:
    """(the largest element of |R^T R - I|, det R) of a row-major 9-tuple."""
    a, b, c, d, e, f, g, h, i = r
    err = max(abs(a * a + d * d + g * g - 1.0), abs(b * b + e * e + h * h - 1.0),
              abs(c * c + f * f + i * i - 1.0), abs(a * b + d * e + g * h),
              abs(a * c + d * f + g * i), abs(b * c + e * f + h * i))
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return err, det


rotation_defect = rotation_defect_kernel.py_func


@kernel()
def quantized_kernel(value: float, resolution: float) -> float:
    """A scale's reading: ``value`` rounded to the nearest multiple of ``resolution``
    (halves to even)."""
    return round(value / resolution) * resolution


quantized = quantized_kernel.py_func


@kernel()
def tool_in_world_kernel(p_bp, r_bp, p_wb, r_wb, r_pt, p_tp) -> tuple:
    """The tool pose in world (position, row-major rotation) of the plate pose in the
    Gough base frame (module doc): R_t = R_wb R_bp R_tp^T, p_t = p_wb + R_wb p_bp - R_t p_tp."""
    r_t = mul3_kernel(r_wb, mul3_kernel(r_bp, r_pt))
    wp = mv3_kernel(r_wb, p_bp)
    rp = mv3_kernel(r_t, p_tp)
    return (p_wb[0] + wp[0] - rp[0], p_wb[1] + wp[1] - rp[1], p_wb[2] + wp[2] - rp[2]), r_t


tool_in_world = tool_in_world_kernel   # for Python callers too (tuples; ~1 us, its py_func ~2 us)


@kernel()
def plate_in_base_kernel(p_t, r_t, p_wb, r_bw, r_tp, p_tp) -> tuple:
    """The plate pose in the Gough base frame (position, row-major rotation) of a tool
    pose in world, the inverse of ``tool_in_world_kernel``: T_base_plate =
    T_world_base^-1 T_world_tool T_tool_plate, R_bp = R_wb^T R_t R_tp,
    p_bp = R_wb^T (p_t + R_t p_tp - p_wb)."""
    rp = mv3_kernel(r_t, p_tp)
    d = (p_t[0] + rp[0] - p_wb[0], p_t[1] + rp[1] - p_wb[1], p_t[2] + rp[2] - p_wb[2])
    return mv3_kernel(r_bw, d), mul3_kernel(r_bw, mul3_kernel(r_t, r_tp))


# Codes of the compiled reading (GoughSensorModel.measure_fields, estimate_into), apart
# from the DKM's (bars.FK_*, gough.DKM_*: >= 0, READ_OK is FK_CONVERGED). What is refused
# is taken again by the interpreted path, which names the error.
READ_OK = FK_CONVERGED
READ_REFUSED, READ_OUTSIDE_TRAVEL, READ_NOT_FINITE, READ_POSE_NOT_FINITE = -1, -2, -3, -4


@kernel("(float64[::1], float64[:, :], float64[::1])")
def true_lengths_kernel(pose, bars, out):
    """The true strut lengths into ``out`` (6,) of a tool pose's fields (x, y, z, qx,
    qy, qz, qw) as a true_pose message carries them, with its checks
    (pose_from_components, rotation_floats): READ_OK, or READ_REFUSED and nothing
    written."""
    px, py, pz, x, y, z, w = pose[0], pose[1], pose[2], pose[3], pose[4], pose[5], pose[6]
    if not math.isfinite(px + py + pz) or not math.isfinite(x + y + z + w):
        return READ_REFUSED
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if abs(norm - 1.0) > QUATERNION_NORM_TOL:
        return READ_REFUSED
    r = unit_quaternion_rotation_kernel(x / norm, y / norm, z / norm, w / norm)
    err, det = rotation_defect_kernel(r)
    if err > ROTATION_TOL or det <= 0.0:
        return READ_REFUSED
    out[:] = strut_lengths_kernel(bars, px, py, pz, r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8])
    return READ_OK


@kernel("(float64[::1], float64[::1], float64, float64[::1])")
def readings_kernel(true_lengths, noise, resolution, out):
    """The scales' readings into ``out``: true length + noise, quantised (measure)."""
    for k in range(6):
        out[k] = quantized_kernel(true_lengths[k] + noise[k], resolution)


@kernel("(float64[::1], float64, float64, float64[:, :], float64[::1], int64[:], float64, int64, float64, float64, "
        "float64[::1], float64[::1], float64[:, ::1], float64[::1])")
def estimate_kernel(lengths, lo, hi, bars, state, flags, tol_m, max_iterations, divergence_limit, home_det_sign,
                    mounting, p, rotation, pose):
    """The tool pose of six readings (estimate: the travel check, the warm-started DKM
    on the nominal geometry, the tool in world) into ``pose`` (x, y, z, qx, qy, qz,
    qw, as pose_components gives it). ``mounting``: p_wb (3), R_wb (9), R_pt (9),
    p_tp (3). Returns (code, iterations, J_h evaluations, residual): READ_OUTSIDE_TRAVEL
    and READ_NOT_FINITE before the solve, the solve's code after it (its last iterate
    in ``p``, ``rotation``), READ_POSE_NOT_FINITE for a converged solve whose tool pose
    is not finite."""
    for k in range(6):
        if not math.isfinite(lengths[k]):
            return READ_NOT_FINITE, 0, 0, math.nan
    for k in range(6):
        if not lo <= lengths[k] <= hi:
            return READ_OUTSIDE_TRAVEL, 0, 0, math.nan
    code, iterations, evaluations, residual = dkm_solve_kernel(bars, lengths, state, flags, tol_m, max_iterations,
                                                              divergence_limit, home_det_sign, p, rotation)
    if code != FK_CONVERGED:
        return code, iterations, evaluations, residual
    m = mounting
    rt = rotation
    (x, y, z), r_t = tool_in_world_kernel(
        (p[0], p[1], p[2]), (rt[0, 0], rt[0, 1], rt[0, 2], rt[1, 0], rt[1, 1], rt[1, 2], rt[2, 0], rt[2, 1], rt[2, 2]),
        (m[0], m[1], m[2]), (m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11]),
        (m[12], m[13], m[14], m[15], m[16], m[17], m[18], m[19], m[20]), (m[21], m[22], m[23]))
    total = x + y + z
    for v in r_t:
        total += v
    if not math.isfinite(total):
        return READ_POSE_NOT_FINITE, iterations, evaluations, residual
    qx, qy, qz, qw = rotation_quaternion_kernel(r_t)
    pose[0], pose[1], pose[2], pose[3], pose[4], pose[5], pose[6] = x, y, z, qx, qy, qz, qw
    return code, iterations, evaluations, residual


_MESSAGE = "Array(uint8, 1, 'C', readonly=True)"      # a received message's bytes (np.frombuffer)


@kernel(f"({_MESSAGE}, int64, float64[::1], float64[:, :], float64[::1], float64[::1], float64, float64[::1], "
        "uint8[::1], int64)")
def measure_message_kernel(pose_msg, pose_at, fields, bars, true_out, noise, resolution, lengths, struts_msg,
                           struts_at):
    """true_lengths_kernel and readings_kernel of a true pose message's bytes (its 7
    values at ``pose_at``, copied into ``fields``), the readings into ``lengths`` and,
    with the message's stamp, into the bytes of a struts message (its positions at
    ``struts_at``): (READ_OK, the stamp in ns), or (READ_REFUSED, 0) with nothing
    written for a pose or a stamp the decoded path refuses."""
    code, stamp_ns = read_stamp(pose_msg)
    if code != STAMP_OK:
        return READ_REFUSED, np.int64(0)
    read_doubles(pose_msg, pose_at, fields, 7)
    if true_lengths_kernel(fields, bars, true_out) != READ_OK:
        return READ_REFUSED, np.int64(0)
    readings_kernel(true_out, noise, resolution, lengths)
    copy_stamp(pose_msg, struts_msg)
    write_doubles(lengths, 6, struts_msg, struts_at)
    return READ_OK, stamp_ns


_true_lengths_call = direct_call(true_lengths_kernel)
_measure_message_call = direct_call(measure_message_kernel)
_readings_call = direct_call(readings_kernel)
_estimate_call = direct_call(estimate_kernel)


def rotation_floats(value, name: str) -> tuple:
    """A rotation matrix as a row-major 9-tuple; ValueError naming ``name`` for a
    wrong shape, NaN/inf, or a matrix that is not a rotation (|R^T R - I| > 1e-6 or
    det <= 0: six strut lengths cannot see a non-rigid plate). ~3 us on floats."""
    try:
        rows = value.tolist() if isinstance(value, np.ndarray) else [list(row) for row in value]
        if len(rows) != 3 or len(rows[0]) != 3 or len(rows[1]) != 3 or len(rows[2]) != 3:
            raise TypeError
        a, b, c, d, e, f, g, h, i = flat = tuple(map(float, rows[0] + rows[1] + rows[2]))
    except (TypeError, ValueError):
        raise FieldError(name, f'expected a 3 x 3 rotation matrix, got {value!r}') from None
    if not math.isfinite(a + b + c + d + e + f + g + h + i):
        raise FieldError(name, f'contains NaN or infinite values: {list(flat)}')
    err, det = rotation_defect(flat)    # columns orthonormal (R^T R = I) and det = +1
    if err > ROTATION_TOL or det <= 0.0:
        raise FieldError(name, f'not a rotation matrix (|R^T R - I| = {err:.3g}, det = {det:.6g})')
    return flat


class GoughSensorModel:
    """Measure strut lengths of a tool pose (true geometry) and estimate the pose
    back from them (nominal geometry, warm-started DKM). See the module docstring.

    ``noise_std_m``: Gaussian noise on each strut reading (m, >= 0).
    ``seed``: seeds the calibration error and the noise stream (independently).
    ``calibration_error_m``: std of the per-axis error of every joint centre (m, >= 0).
    ``resolution_m``: scale resolution (m, in (0, 1e-3]); None: the machine file's
    ``encoder_resolution`` (MoM3 §4.3: 1 um). Readings are rounded to the nearest
    multiple of it.
    """

    def __init__(self, metrology: GoughMetrologyConfig, noise_std_m: float = 0.0, seed: int = 0,
                 calibration_error_m: float = 0.0, resolution_m: float | None = None):
        if not isinstance(metrology, GoughMetrologyConfig):
            raise FieldError('metrology', f'expected a GoughMetrologyConfig (the machine file\'s '
                                          f'metrology section), got {type(metrology).__name__}')
        self.noise_std_m = _nonneg(noise_std_m, 'noise_std_m')
        self.calibration_error_m = _nonneg(calibration_error_m, 'calibration_error_m')
        if resolution_m is None:
            resolution_m = metrology.encoder_resolution_m
        res = _nonneg(resolution_m, 'resolution_m')
        if not 0.0 < res <= MAX_RESOLUTION_M:
            raise FieldError('resolution_m', f'must be in (0, {MAX_RESOLUTION_M:g}] m, got {resolution_m!r}')
        self.resolution_m = res
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise FieldError('seed', f'expected an integer >= 0, got {seed!r}')
        self.seed = int(seed)
        self.metrology = metrology
        self.nominal: GoughPlatform = metrology.platform

        # independent streams: the true geometry depends on the seed only, not on how
        # many readings were taken
        calibration_seq, noise_seq = np.random.SeedSequence(self.seed).spawn(2)
        cal = np.random.default_rng(calibration_seq)
        base_err = cal.normal(0.0, 1.0, (6, 3)) * self.calibration_error_m
        plate_err = cal.normal(0.0, 1.0, (6, 3)) * self.calibration_error_m
        self.true_platform = GoughPlatform(
            self.nominal.base_points + base_err, self.nominal.plate_points + plate_err,
            self.nominal.strut_limits, self.nominal.home_position, name='gough_true')
        self._noise = NormalDraws(np.random.default_rng(noise_seq), self.noise_std_m)    # drawn ahead

        # mounting as floats
        self._p_wb = tuple(float(v) for v in metrology.base_position)
        self._r_wb = rotation_floats(metrology.base_rotation, 'metrology.base_rotation')
        self._r_bw = _t(self._r_wb)
        self._p_tp = tuple(float(v) for v in metrology.plate_position_in_tool)
        self._r_tp = rotation_floats(metrology.plate_rotation_in_tool, 'metrology.plate_rotation_in_tool')
        self._r_pt = _t(self._r_tp)
        # the true joint centres in the frames where measure() needs them: A_i in
        # world (p_wb + R_wb A_i), b_i in the tool frame (p_tp + R_tp b_i); then
        # l_i = |p_t + R_t b_i - A_i| needs no mounting transform per reading
        base_w = np.asarray(metrology.base_position) + self.true_platform.base_points @ np.asarray(
            metrology.base_rotation).T
        plate_t = np.asarray(metrology.plate_position_in_tool) + self.true_platform.plate_points @ np.asarray(
            metrology.plate_rotation_in_tool).T
        self._true_bars = bar_rows(base_w, plate_t, actuator=np.arange(6), kind=STRUT)

        # DKM tolerance: 1/1000 of the resolution. The strut residual then adds at most
        # 0.1 % to the quantisation error (|dl_i| <= res/2 + tol), and a warm-started
        # solve mostly needs one Newton step instead of two (~10 us less per reading).
        self.dkm_tol_m = DKM_TOL_FRACTION * self.resolution_m
        self.solver = GoughDKMSolver(self.nominal, tol_m=self.dkm_tol_m)
        self._travel = (float(self.nominal.strut_limits[0]), float(self.nominal.strut_limits[1]))
        # the compiled reading's arrays (measure_fields, estimate_into)
        self._true_out, self._no_noise = np.empty(6), np.zeros(6)
        self._dkm_p, self._dkm_rotation = np.empty(3), np.empty((3, 3))
        self._mounting = np.array(self._p_wb + self._r_wb + self._r_pt + self._p_tp, dtype=float)

    # ------------------------------------------------------------- frames
    @property
    def base_rotation_floats(self) -> tuple:
        """R_wb, the Gough base's rotation in the world, row-major (9 floats)."""
        return self._r_wb

    @property
    def plate_position_in_tool(self) -> tuple:
        """p_tp, the plate centre in the tool frame (3 floats, m)."""
        return self._p_tp

    def plate_in_base(self, p_t, r_t) -> tuple[tuple, tuple]:
        """:meth:`plate_pose` on floats, unchecked (per-cycle use): tool position (3
        floats) and row-major rotation (9 floats) -> plate position and rotation."""
        return plate_in_base_kernel(tuple(p_t), tuple(r_t), self._p_wb, self._r_bw, self._r_tp, self._p_tp)

    @property
    def plate_constants(self) -> tuple:
        """(p_wb, R_wb^T, R_tp, p_tp): the mounting as ``plate_in_base_kernel`` takes it."""
        return self._p_wb, self._r_bw, self._r_tp, self._p_tp

    def _tool_in_world(self, p_bp, r_bp) -> tuple[tuple, tuple]:
        return tool_in_world(tuple(p_bp), tuple(r_bp), self._p_wb, self._r_wb, self._r_pt, self._p_tp)

    def plate_pose(self, tool_position, tool_rotation) -> tuple[np.ndarray, np.ndarray]:
        """The Gough plate pose in the Gough base frame for a tool pose in world."""
        p, r = self.plate_in_base(finite_floats(tool_position, 3, 'tool_position'),
                                   rotation_floats(tool_rotation, 'tool_rotation'))
        return np.array(p), np.array(r).reshape(3, 3)

    def tool_pose(self, plate_position, plate_rotation) -> tuple[np.ndarray, np.ndarray]:
        """The tool pose in world for a Gough plate pose in the Gough base frame."""
        p, r = self._tool_in_world(finite_floats(plate_position, 3, 'plate_position'),
                                   rotation_floats(plate_rotation, 'plate_rotation'))
        return np.array(p), np.array(r).reshape(3, 3)

    # ----------------------------------------------------------- measuring
    def true_lengths(self, tool_position, tool_rotation) -> np.ndarray:
        """Exact strut lengths of the true geometry (no noise, no quantisation)."""
        return np.array(self._true_lengths(finite_floats(tool_position, 3, 'tool_position'),
                                           rotation_floats(tool_rotation, 'tool_rotation')))

    def _true_lengths(self, p_t, r_t) -> list:
        # A_i in world, b_i in the tool frame: no mounting transform per reading
        return strut_lengths_kernel(self._true_bars, p_t[0], p_t[1], p_t[2], *r_t).tolist()

    def strut_segments(self, tool_position, tool_rotation) -> list[tuple[list, list]]:
        """(base joint, plate joint) of every strut in world coordinates for a tool pose
        (the true geometry): what a drawing of the sensor needs."""
        p = np.asarray(finite_floats(tool_position, 3, 'tool_position'))
        r = np.asarray(rotation_floats(tool_rotation, 'tool_rotation')).reshape(3, 3)
        bars = self._true_bars
        return [(a.tolist(), (p + r @ b).tolist()) for a, b in zip(bars[:, COL_A:COL_A + 3], bars[:, COL_B:COL_B + 3])]

    def measure(self, tool_position, tool_rotation) -> np.ndarray:
        """Strut readings (6,) for a tool pose in world: true lengths + N(0, noise_std),
        rounded to the nearest multiple of the resolution (MoM3 §4.3 linear scales)."""
        lengths = self._true_lengths(finite_floats(tool_position, 3, 'tool_position'),
                                     rotation_floats(tool_rotation, 'tool_rotation'))
        if self.noise_std_m > 0.0:
            noise = self._noise.take(6).tolist()
            lengths = [a + b for a, b in zip(lengths, noise)]
        res = self.resolution_m
        return np.array([quantized(v, res) for v in lengths])

    # ---------------------------------------------------------- estimating
    def estimate(self, lengths) -> tuple[np.ndarray, np.ndarray, GoughDKMResult]:
        """Tool pose in world from strut readings: DKM_GP on the nominal geometry
        (MoM3 §6.3), warm-started from the previous solutions.

        Returns (position (3,), rotation (3, 3), result). The pose is NaN and
        ``result.reason`` says why when a reading lies outside the strut travel
        (``strut_limits``: the real scales cannot read there, the DKM is not tried) or
        the DKM fails; never the previous pose passed off as new. ValueError for
        lengths that are not 6 finite positive numbers.
        """
        values = finite_floats(lengths, 6, 'strut lengths')
        lo, hi = self._travel
        if not lo <= min(values) or not max(values) <= hi:
            k = next(k for k, v in enumerate(values) if not lo <= v <= hi)
            reason = (f'{STRUT_NAMES[k]}: {values[k]:.6f} m outside the strut travel '
                      f'[{lo:g}, {hi:g}] m')
            result = GoughDKMResult(np.full(3, np.nan), np.full((3, 3), np.nan), False, 0, 0, math.nan, reason)
            return result.position, result.rotation, result
        result = self.solver.solve(values)
        if not result.converged:
            return np.full(3, np.nan), np.full((3, 3), np.nan), result
        p, r = self._tool_in_world(result.position.tolist(), tuple(result.rotation.ravel().tolist()))
        return np.array(p), np.array(r).reshape(3, 3), result

    # ------------------------------------------------ the compiled reading
    # measure() and estimate() of one true pose in three compiled calls (~1 us each
    # against ~25 us interpreted), the same floats: the kernels are made of the
    # functions these methods call (rotations' kernels, quantized, tool_in_world, the
    # solver's dkm_solve_kernel). What they refuse is taken again by measure() or
    # estimate(), which name the error.
    def measure_fields(self, fields: np.ndarray, out: np.ndarray) -> bool:
        """:meth:`measure` of a true tool pose given as its message's fields (7 float64:
        x, y, z, qx, qy, qz, qw, as pose_from_components reads them) into ``out`` (6
        float64). False, with no noise drawn and nothing written, for a pose that
        pose_from_components or measure() refuses."""
        if _true_lengths_call(fields, self._true_bars, self._true_out) != READ_OK:
            return False
        noise = self._noise.take(6) if self.noise_std_m > 0.0 else self._no_noise
        _readings_call(self._true_out, noise, self.resolution_m, out)
        return True

    def measure_message(self, pose_msg: np.ndarray, pose_at: int, fields: np.ndarray, lengths: np.ndarray,
                        struts_msg: np.ndarray, struts_at: int) -> int | None:
        """:meth:`measure_fields` of a true pose message's bytes (``pose_msg``, uint8, its
        values at ``pose_at``; copied into ``fields``), the readings into ``lengths`` and
        into the bytes of a struts message (``struts_msg``, its stamp and its positions at
        ``struts_at``): the stamp in ns, or None, with no noise drawn and nothing
        written, for a message the decoded path must take."""
        noise = self._noise.peek(6) if self.noise_std_m > 0.0 else self._no_noise
        code, stamp_ns = _measure_message_call(pose_msg, pose_at, fields, self._true_bars, self._true_out, noise,
                                               self.resolution_m, lengths, struts_msg, struts_at)
        if code != READ_OK:
            return None
        if self.noise_std_m > 0.0:
            self._noise.take(6)
        return stamp_ns

    def estimate_into(self, lengths: np.ndarray, pose: np.ndarray) -> GoughDKMResult | None:
        """:meth:`estimate` of readings ``lengths`` (6 float64), the tool pose into
        ``pose`` as pose_components gives it (x, y, z, qx, qy, qz, qw): None when it
        converged, else the failed result estimate() gives (the DKM state as after it).
        Raises what estimate() and pose_components raise."""
        solver = self.solver
        bars, state, flags, tol_m, max_iterations, divergence_limit, det_sign = solver.kernel_arguments()
        p, rotation = self._dkm_p, self._dkm_rotation
        code, iterations, evaluations, residual = _estimate_call(
            lengths, self._travel[0], self._travel[1], bars, state, flags, tol_m, max_iterations, divergence_limit,
            det_sign, self._mounting, p, rotation, pose)
        if code == READ_OK:
            return None
        if code in (READ_OUTSIDE_TRAVEL, READ_NOT_FINITE):      # before the solve: the state untouched
            return self.estimate(lengths.tolist())[2]
        if code == READ_POSE_NOT_FINITE:                          # raises, naming it
            p_t, r_t = self._tool_in_world(p.tolist(), tuple(rotation.ravel().tolist()))
            pose_components(np.array(p_t), np.array(r_t).reshape(3, 3))
        return solver.result_of(code, p, rotation, iterations, evaluations, residual)

    def reset(self, tool_position=None, tool_rotation=None) -> None:
        """Restart the DKM warm start from a tool pose (default: the platform's home)."""
        if tool_position is None:
            self.solver.reset()
            return
        p, r = self.plate_pose(tool_position, tool_rotation)
        self.solver.reset(p, r)
