"""CAN bus time of a control cycle (pkm_drives.bus_timing) against a bit-by-bit count:
the frames of real payloads are built bit by bit (SOF..EOF), stuffed, and counted; the
worst case of the formula bounds every one of them and is reached by a payload."""

import random

import pytest

from pkm_drives.bus_timing import check_rate, cycle_load, frame_bits
from pkm_kinematics.errors import FieldError


def crc15(bits):
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return [(crc >> (14 - k)) & 1 for k in range(15)]


def stuffed_frame_bits(can_id: int, data: bytes) -> int:
    """Bits of a CAN 2.0A data frame with its real stuffing (ISO 11898-1)."""
    head = [0] + [(can_id >> (10 - k)) & 1 for k in range(11)] + [0, 0, 0] + \
        [(len(data) >> (3 - k)) & 1 for k in range(4)]
    body = head + [(byte >> (7 - k)) & 1 for byte in data for k in range(8)]
    body += crc15(body)
    stuffed, run, last = 0, 0, None
    for b in body:
        run = run + 1 if b == last else 1
        last = b
        if run == 5:
            stuffed += 1
            last, run = 1 - b, 1            # the stuff bit is the complement and starts a new run
    return len(body) + stuffed + 1 + 2 + 7 + 3     # CRC delimiter, ACK slot + delimiter, EOF, intermission


def test_formula_bounds_real_frames_and_is_reached():
    rng = random.Random(7)
    for n in range(9):
        bound = frame_bits(n)
        assert bound == 47 + 8 * n + (34 + 8 * n - 1) // 4
        seen = [stuffed_frame_bits(rng.randrange(0x800), bytes(rng.randrange(256) for _ in range(n)))
                for _ in range(300)]
        assert max(seen) <= bound and min(seen) >= 47 + 8 * n, (n, min(seen), max(seen), bound)
    # all-zero identifier and data: a stuff bit after every run of five, close to the bound
    assert stuffed_frame_bits(0x000, bytes(8)) > 47 + 64 + 12


def test_four_drives_at_1_mbit_need_more_than_a_millisecond():
    # ARCHI: 4 drives, RPDO controlword + target torque (4 bytes), TPDO1 statusword +
    # position + torque (8 bytes), TPDO2 velocity (4 bytes)
    load = cycle_load(1_000_000, 0.001, [[4]] * 4, [[8, 4]] * 4)
    assert load.bits == 55 + 4 * (95 + 135 + 95)
    assert load.cycle_s == pytest.approx(1.355e-3)
    with pytest.raises(FieldError) as info:
        check_rate(load)
    assert info.value.name == "dt_s" and "1.355 ms" in str(info.value) and "1 ms" in str(info.value), str(info.value)
    check_rate(cycle_load(1_000_000, 0.002, [[4]] * 4, [[8, 4]] * 4))     # 500 Hz is carried
    # heartbeats add their share: 6 drives at 10 ms add 6 * 65 bits over 10 cycles of 1 ms
    with_hb = cycle_load(1_000_000, 0.001, [[4]] * 6, [[8]] * 6, heartbeat_s=0.01)
    without = cycle_load(1_000_000, 0.001, [[4]] * 6, [[8]] * 6)
    assert (with_hb.cycle_s - without.cycle_s) * 1e6 == pytest.approx(6 * 65 / 10)


@pytest.mark.parametrize("bad", [-1, 9])
def test_frame_bits_refuses_impossible_payloads(bad):
    with pytest.raises(FieldError, match="data_bytes"):
        frame_bits(bad)


def test_frames_listed_per_cycle():
    load = cycle_load(500_000, 0.004, [[4], [4]], [[8, 4], [8, 4]])
    assert load.frames == (0, 4, 4, 8, 4, 8, 4)
    assert sum(frame_bits(b) for b in load.frames) == load.bits


def test_a_timed_virtual_bus_takes_each_frames_transmission_time():
    """pkm_drives.bus.TimedBus: 60 frames of 8 bytes from two senders sharing one wire at
    125 kbit/s take 60 x 135 bits = 64.8 ms at least; untimed they take ~1 ms."""
    import time

    import can

    from pkm_drives.bus import TimedBus
    channel = "test_timed_bus"
    senders = [TimedBus(can.Bus(interface="virtual", channel=channel), channel, 125_000) for _ in range(2)]
    reader = can.Bus(interface="virtual", channel=channel)
    try:
        start = time.perf_counter()
        for k in range(30):
            for bus in senders:
                bus.send(can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False))
        elapsed = time.perf_counter() - start
        received = 0
        while reader.recv(0.2) is not None:
            received += 1
    finally:
        for bus in senders + [reader]:
            bus.shutdown()
    assert received == 60
    assert 60 * 135 / 125_000 <= elapsed + 3e-4 < 0.5, elapsed
