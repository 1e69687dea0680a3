"""Compiled access to the fixed fields of serialized messages (pure, no rclpy): a
kernel that reads a message's float64 arrays from its CDR bytes or writes them into a
message's bytes, without making a Python float of each (pkm_common.cdr's codecs take
~1-2 us a message in a loop's context, most of it the floats and tuples).

The fields of a stream of one layout (pkm_common.cdr.JointStateEncoder,
PoseStampedEncoder: the same names and frame every message) sit at fixed offsets,
which the encoders give (``offsets``, ``values_offset``). CDR aligns a float64 to 8
bytes from the start of the body, 4 bytes into the message: the doubles are copied
byte by byte between the message and an aligned array (little-endian, as the CDR
header of these messages and this machine)."""

from __future__ import annotations

import numpy as np

from pkm_kinematics.jit import kernel

__all__ = ["NS_PER_S", "STAMP_OK", "STAMP_REFUSED", "copy_stamp", "read_doubles", "read_stamp", "write_doubles"]

NS_PER_S = 1_000_000_000
STAMP_OK, STAMP_REFUSED = 0, 1


@kernel()
def read_doubles(buf, offset, out, count):
    """``count`` float64 of ``buf`` (uint8) from byte ``offset`` into ``out[:count]`` (a
    contiguous float64 array)."""
    raw = out.view(np.uint8)
    for k in range(8 * count):
        raw[k] = buf[offset + k]


@kernel()
def write_doubles(values, count, buf, offset):
    """``values[:count]`` (a contiguous float64 array) into ``buf`` (uint8) from byte ``offset``."""
    raw = values.view(np.uint8)
    for k in range(8 * count):
        buf[offset + k] = raw[k]


@kernel()
def read_stamp(buf):
    """(STAMP_OK, header.stamp in ns) of a stamped message's bytes, or (STAMP_REFUSED, 0)
    for a stamp cdr's decoders refuse (before 1970, nanosec of a second or more)."""
    sec = np.int64(0)
    for k in range(3, -1, -1):
        sec = (sec << 8) | np.int64(buf[4 + k])
    if sec >= 2**31:
        sec -= 2**32                     # an int32
    nanosec = np.int64(0)
    for k in range(3, -1, -1):
        nanosec = (nanosec << 8) | np.int64(buf[8 + k])
    if sec < 0 or nanosec >= NS_PER_S:
        return STAMP_REFUSED, np.int64(0)
    return STAMP_OK, sec * NS_PER_S + nanosec


@kernel()
def copy_stamp(source, target):
    """header.stamp of the message ``source`` into the message ``target`` (bytes 4-12)."""
    for k in range(4, 12):
        target[k] = source[k]
