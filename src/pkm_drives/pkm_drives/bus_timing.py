"""How long a CAN bus takes to carry one control cycle, and the rate it allows (pure).

A classic CAN data frame with an 11-bit identifier (CAN 2.0A, ISO 11898-1) is
SOF 1 + identifier 11 + RTR 1 + IDE 1 + r0 1 + DLC 4 + data 8n + CRC 15 + CRC delimiter 1
+ ACK 2 + EOF 7 + intermission 3 = 47 + 8n bits. Bit stuffing inserts a bit after five
equal ones in SOF..CRC (34 + 8n bits); at worst one stuff bit per four bits after the
first: floor((34 + 8n - 1) / 4). The bound used here is that worst case, so a rate it
accepts is carried whatever the data (Davis et al., "Controller Area Network (CAN)
schedulability analysis: refuted, revisited and revised", Real-Time Systems 35, 2007,
eq. 1).

One cycle of the drive interface is the SYNC (no data) and, per drive, its RPDOs and
its TPDOs; heartbeats add one 1-byte frame per drive per heartbeat period.
"""

from __future__ import annotations

from dataclasses import dataclass

from pkm_kinematics.errors import FieldError

__all__ = ["frame_bits", "CycleLoad", "cycle_load", "check_rate"]

SYNC_BYTES = 0
HEARTBEAT_BYTES = 1


def frame_bits(data_bytes: int) -> int:
    """Bits on the wire of one CAN 2.0A data frame of ``data_bytes`` (0-8), worst-case
    stuffing included (the module's formula)."""
    if not 0 <= data_bytes <= 8:
        raise FieldError.out_of_range("data_bytes", "in [0, 8]", data_bytes)
    return 47 + 8 * data_bytes + (34 + 8 * data_bytes - 1) // 4


@dataclass(frozen=True)
class CycleLoad:
    """The bus time of one control cycle at ``bitrate``: its ``frames`` (data bytes of
    each), ``bits`` (worst case), ``cycle_s`` (those bits' time, heartbeats' share
    included), and against the ``period_s`` asked for: ``load`` (cycle_s / period_s)
    and ``max_rate_hz`` (1 / cycle_s)."""

    bitrate: int
    frames: tuple[int, ...]
    bits: int
    cycle_s: float
    period_s: float

    @property
    def load(self) -> float:
        return self.cycle_s / self.period_s

    @property
    def max_rate_hz(self) -> float:
        return 1.0 / self.cycle_s

    def describe(self) -> str:
        return (f"{len(self.frames)} frames, {self.bits} bits a cycle: {self.cycle_s * 1e3:.3f} ms at "
                f"{self.bitrate / 1e6:g} Mbit/s (at most {self.max_rate_hz:.0f} Hz); the period asks for "
                f"{self.period_s * 1e3:g} ms ({self.load:.0%} of the bus)")


def cycle_load(bitrate: int, period_s: float, rpdo_bytes: list[list[int]], tpdo_bytes: list[list[int]],
               heartbeat_s: float = 0.0) -> CycleLoad:
    """The bus time of one cycle: a SYNC, then each drive's RPDOs and TPDOs (data
    bytes of each, one list per drive), plus one heartbeat frame per drive every
    ``heartbeat_s`` (0: none) averaged over the cycles of its period."""
    if bitrate <= 0:
        raise FieldError.out_of_range("bitrate", "> 0 bit/s", bitrate)
    if not period_s > 0.0:
        raise FieldError.out_of_range("dt_s", "> 0 s", period_s)
    frames = (SYNC_BYTES,) + tuple(b for drive in rpdo_bytes for b in drive) + \
        tuple(b for drive in tpdo_bytes for b in drive)
    bits = sum(frame_bits(b) for b in frames)
    heartbeat_bits = 0.0
    if heartbeat_s > 0.0:
        heartbeat_bits = len(tpdo_bytes) * frame_bits(HEARTBEAT_BYTES) * period_s / heartbeat_s
    return CycleLoad(int(bitrate), frames, bits, (bits + heartbeat_bits) / bitrate, float(period_s))


def check_rate(load: CycleLoad) -> None:
    """FieldError ``dt_s`` when the bus cannot carry a cycle within the period, naming
    the figures (e.g. "4 drives ... 1.355 ms at 1 Mbit/s ... asks for 1 ms")."""
    if load.cycle_s > load.period_s:
        raise FieldError("dt_s", f"the CAN bus cannot carry the cycle: {load.describe()}; "
                         f"choose dt_s >= {load.cycle_s:.4g} s, a higher bitrate or fewer PDOs",
                         allowed=f">= {load.cycle_s:.4g} s", got=load.period_s)
