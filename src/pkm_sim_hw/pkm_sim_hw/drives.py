"""What every simulated machine's drives do, whatever moves the platform (no rclpy):
force saturation and the no-force fault (``applied_forces``), the encoders
(``Encoders``: an unknown offset until homed, quantised at the resolution, optional
Gaussian noise, velocity by backward difference; ``encoder_freeze`` holds the last
reading, ``encoder_slip`` adds its constant offset), and a drive's homing motion
(``HomingMotion``). ``plant.Plant`` (rails) and ``strut_plant.StrutPlant`` (struts)
both use them; pkm_drives' virtual CiA 402 drives run the homing motion."""

from __future__ import annotations

import math

import numpy as np

from pkm_common.noise import NormalDraws
from pkm_kinematics.jit import kernel


@kernel()
def saturated_force(commanded, limit):
    """(applied, saturated): a drive's commanded force clamped to +-``limit``;
    saturated: the command was beyond it."""
    return max(-limit, min(limit, commanded)), abs(commanded) > limit


@kernel()
def encoder_reading(q, screw_error, wavenumber, offset, noise, resolution):
    """A drive's encoder reading at its true position ``q``: the screw error
    A sin(k q), the offset, the noise (this step's draw), then quantised at the
    resolution (none at 0). A zero term adds nothing."""
    if screw_error != 0.0:
        q = q + screw_error * math.sin(wavenumber * q)
    if offset != 0.0:
        q = q + offset
    if noise != 0.0:
        q = q + noise
    if resolution > 0.0:
        q = round(q / resolution) * resolution
    return q


_saturated_force, _encoder_reading = saturated_force.py_func, encoder_reading.py_func


@kernel("(float64[::1], float64, float64[::1], boolean[::1])")
def saturated_forces(commanded, limit, applied, saturated):
    """``saturated_force`` of every drive into ``applied`` and ``saturated`` (a compiled
    plant step's); False, nothing written, when a command is not finite."""
    total = 0.0
    for i in range(commanded.shape[0]):
        total += commanded[i]
    if not math.isfinite(total):
        return False
    for i in range(commanded.shape[0]):
        applied[i], saturated[i] = saturated_force(commanded[i], limit)
    return True


def take_commands(cmd: np.ndarray, forces) -> bool:
    """``forces`` copied into ``cmd`` (a compiled plant step's n floats) when they are
    n finite numbers; False otherwise: the interpreted step refuses them, naming why."""
    if len(forces) != len(cmd):
        return False
    try:
        cmd[:] = forces
    except (TypeError, ValueError):
        return False
    return math.isfinite(sum(forces))


def applied_forces(commanded, limit: float, faults) -> tuple[list, list]:
    """(applied, saturated): each command clamped to +-``limit`` (``saturated_force``),
    zero on a drive with an active ``no_force`` fault."""
    pairs = [_saturated_force(f, limit) for f in commanded]
    applied, saturated = [a for a, _ in pairs], [s for _, s in pairs]
    for f in faults:
        if f.kind == "no_force":
            applied[f.drive] = 0.0
    return applied, saturated


_NO_NOISE = np.zeros(0)


class Encoders:
    """The drive encoders of one plant: ``read(q_true, faults)`` once per step.
    ``offsets``: incremental encoders count from where they were at power-up, not from
    the machine's zero: each reads its drive's position plus its offset (unknown to the
    controller until the drive is homed: HomingMotion). ``screw_errors``: each drive's
    screw (or scale) error, the reading's periodic departure from the true position,
    A_k sin(2 pi q / ``screw_period_m``) (a ball screw's cumulative lead error along its
    travel: what a compensation table, LinuxCNC's COMP_FILE, takes out)."""

    def __init__(self, resolution_m: float, noise_m: float, seed: int, dt_s: float, offsets=(),
                 screw_errors=(), screw_period_m: float = 0.1):
        self.resolution_m, self.noise_m, self.dt_s = resolution_m, noise_m, dt_s
        self.offsets = [float(o) for o in offsets]
        self.screw_errors = [float(a) for a in screw_errors]
        self.screw_wavenumber = 2.0 * math.pi / screw_period_m
        self._draws = NormalDraws(np.random.default_rng(seed), noise_m)      # drawn ahead (``noise``)
        self._kernel_key, self._kernel_arguments = None, ()
        self.last: list = []
        self._last_list, self._last_array = None, np.empty(0)    # ``last`` as the compiled steps take it

    def last_array(self) -> np.ndarray:
        """``last`` as a float64 array, for a compiled step's reading (the same array
        every step; made again when ``last`` was set elsewhere: the start, homing)."""
        if self.last is not self._last_list:
            self._last_list, self._last_array = self.last, np.array(self.last, dtype=float)
        return self._last_array

    def keep(self, reading: np.ndarray) -> list:
        """A compiled step's ``reading`` (made from :meth:`last_array`) as ``last``;
        returns it as the list."""
        self.last = self._last_list = reading.tolist()
        self._last_array[:] = reading
        return self.last

    def kernel_arguments(self) -> tuple:
        """(resolution, offsets, screw errors, screw wavenumber) as a compiled reading
        takes them (``encoder_reading`` per drive: floats and arrays, an empty array for
        none), made again whenever they change (homing gives the encoders their new
        offsets)."""
        key = (self.resolution_m, self.offsets, self.screw_errors, self.screw_wavenumber)
        if key != self._kernel_key:
            self._kernel_key = (key[0], list(key[1]), list(key[2]), key[3])
            self._kernel_arguments = (float(self.resolution_m), np.array(self.offsets, dtype=float),
                                      np.array(self.screw_errors, dtype=float), float(self.screw_wavenumber))
        return self._kernel_arguments

    def quantise(self, q) -> list:
        """Each drive's ``encoder_reading``: screw error, offset, noise (one draw per
        drive), then the resolution."""
        n = len(q)
        screw = self.screw_errors or [0.0] * n
        offsets = self.offsets or [0.0] * n
        noise = self.noise(n).tolist() if self.noise_m > 0.0 else [0.0] * n
        k, res = self.screw_wavenumber, self.resolution_m
        return [_encoder_reading(float(q[i]), screw[i], k, offsets[i], noise[i], res) for i in range(n)]

    def noise(self, n: int) -> np.ndarray:
        """The noise of a step's readings (``n`` drives, the same every step): one draw
        per drive in order, times its std (pkm_common.noise); empty without noise."""
        if self.noise_m <= 0.0:
            return _NO_NOISE
        return self._draws.take(n)

    def start(self, q_true) -> None:
        """The first reading (no velocity before it)."""
        self.last = self.quantise(q_true)

    def read(self, q_true, faults) -> tuple[list, list]:
        """(readings, velocities) of the true drive positions under the active faults."""
        reading = self.quantise(q_true)
        frozen = {f.drive for f in faults if f.kind == "encoder_freeze"}
        for f in faults:
            if f.kind == "encoder_slip":
                reading[f.drive] += f.size
        reading = [self.last[i] if i in frozen else r for i, r in enumerate(reading)]
        velocity = [(r - p) / self.dt_s for r, p in zip(reading, self.last)]
        self.last = reading
        return reading, velocity


# CiA 402 homing methods (0x6098) a simulated drive runs: what it homes on
HOME_SWITCH, INDEX_NEGATIVE, INDEX_POSITIVE, CURRENT_POSITION = (19, 21), 33, 34, (35, 37)


class HomingMotion:
    """One drive's homing as a servo drive runs it in CiA 402 homing mode, on the
    simulated machine: a position reference moving at ``speed`` towards the reference
    mark, followed by the drive's own PID (bandwidth ``bandwidth_hz`` on ``mass_kg``),
    until the mark is crossed; the encoder reading there is latched (interpolated
    between the two samples around the crossing, as a drive's capture input latches
    it), the drive goes back to the mark and holds there (completed: at rest within
    ``tolerance`` of it). The drive's position is then ``reading + shift``,
    ``shift = home_position - latched``.

    The marks, in the drive's true position (its encoder without the offset):
    methods 19 and 21, a home switch's edge at ``home_position`` (the drive moves
    towards it from either side); 33 and 34, index pulses at ``home_position + k pitch``
    (the next one in the negative or positive direction: the drive must start within a
    pitch of its home index); 35 and 37, the current position (no motion).

    ``step(true, reading, velocity)`` after each sample returns the force for the next
    period; ``status``: "in_progress", "attained" (latched, stopping), "completed"
    (stopped), "error" (no mark within ``max_travel``)."""

    def __init__(self, method: int, home_position: float, speed: float, mass_kg: float, dt_s: float,
                 bandwidth_hz: float = 5.0, pitch: float = 0.005, max_travel: float = 0.05, tolerance: float = 2e-6):
        if method not in HOME_SWITCH + CURRENT_POSITION + (INDEX_NEGATIVE, INDEX_POSITIVE):
            raise ValueError(f"homing method {method}: not simulated")
        self.method, self.home, self.speed, self.dt = method, home_position, abs(speed), dt_s
        self.pitch, self.max_travel, self.tolerance = pitch, max_travel, tolerance
        w = 2.0 * math.pi * bandwidth_hz
        self.kp, self.kd, self.ki = mass_kg * w * w, 2.0 * 0.7 * mass_kg * w, mass_kg * w * w * w / 5.0
        self.status = "in_progress"
        self.latched: float | None = None
        self.shift = 0.0
        self.target = None               # the mark's true position
        self.reference = None            # the position reference (reading units), None until the first sample
        self.direction = 0.0
        self.integral = 0.0
        self.previous = None             # (true, reading) of the last sample
        self.start_reading = None

    def _aim(self, true: float) -> None:
        if self.method in CURRENT_POSITION:
            self.target = true
        elif self.method in HOME_SWITCH:
            self.target, self.direction = self.home, (1.0 if self.home >= true else -1.0)
        else:
            k = (true - self.home) / self.pitch
            k = math.floor(k) + 1 if self.method == INDEX_POSITIVE else math.ceil(k) - 1
            self.target, self.direction = self.home + k * self.pitch, (1.0 if self.method == INDEX_POSITIVE else -1.0)

    def step(self, true: float, reading: float, velocity: float) -> float:
        if self.reference is None:                      # the first sample: aim, start from here
            self._aim(true)
            self.reference = self.start_reading = reading
            if self.method in CURRENT_POSITION:
                self._latch(reading)
        elif self.latched is None:
            self.reference += self.direction * self.speed * self.dt
            t0, r0 = self.previous
            if (t0 - self.target) * (true - self.target) <= 0.0 and true != t0:
                self._latch(r0 + (reading - r0) * (self.target - t0) / (true - t0))
                self.reference = self.latched           # back to the mark, and hold there
            elif abs(reading - self.start_reading) > self.max_travel:
                self.status, self.reference = "error", reading
        elif self.status == "attained" and abs(velocity) < 1e-4 and abs(reading - self.reference) <= self.tolerance:
            self.status = "completed"
        self.previous = (true, reading)
        error = self.reference - reading
        self.integral += error * self.dt
        v_ref = self.direction * self.speed if self.latched is None and self.status != "error" else 0.0
        return self.kp * error + self.kd * (v_ref - velocity) + self.ki * self.integral

    def _latch(self, reading: float) -> None:
        self.latched = reading
        self.shift = self.home - reading               # the drive's position at the mark: home_position
        self.status = "attained"
