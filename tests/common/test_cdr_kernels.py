"""The compiled access to a message's fixed fields (pkm_common.cdr_kernels) against
the codecs (pkm_common.cdr): the offsets the encoders give hold the values they
encode, and the kernels read and write them bit for bit."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from pkm_common.cdr import JointStateEncoder, PoseStampedDecoder, PoseStampedEncoder, decode_joint_state
from pkm_common.cdr_kernels import STAMP_OK, STAMP_REFUSED, copy_stamp, read_doubles, read_stamp, write_doubles

VALUES = [1.5, -0.0, math.pi, 1e-300, -2.5e7, math.inf, 7.0]


@pytest.mark.parametrize("names,frame,fields", [
    (["a", "b", "c"], "", ("position", "velocity", "effort")),
    (["rail1", "rail2", "rail3", "rail4"], "safe_stop:estop", ("position", "velocity", "effort")),
    ([f"strut{i}" for i in range(1, 7)], "gough_base", ("position",)),
    (["x"], "f", ("effort",))])
def test_the_offsets_of_a_joint_state_hold_its_arrays_and_the_kernels_read_and_write_them(names, frame, fields):
    enc = JointStateEncoder(names, frame, fields)
    n = len(names)
    arrays = {f: [VALUES[(i + k) % len(VALUES)] for i in range(n)] for k, f in enumerate(enc.FIELDS)}
    msg = enc.encode(12_345_678_901, *(arrays[f] if f in fields else () for f in enc.FIELDS))
    assert sorted(enc.offsets) == sorted(fields)
    buf = np.frombuffer(msg, np.uint8)
    template = np.frombuffer(enc.template(), np.uint8).copy()
    assert decode_joint_state(template.tobytes()).stamp_ns == 0
    for field, at in enc.offsets.items():
        assert list(struct.unpack_from(f"<{n}d", msg, at)) == arrays[field], field
        out = np.empty(n)
        read_doubles(buf, at, out, n)
        assert out.tobytes() == np.array(arrays[field]).tobytes(), field      # -0.0 and inf kept
        write_doubles(out, n, template, at)
    copy_stamp(buf, template)
    assert template.tobytes() == msg                  # every array and the stamp written: the message
    assert read_stamp(buf) == (STAMP_OK, 12_345_678_901)


def test_a_pose_s_values_offset_and_layout():
    enc = PoseStampedEncoder("world")
    msg = enc.encode(3_000_000_007, (1.0, -2.0, 3.5), (0.0, 0.0, 0.6, 0.8))
    assert enc.matches(msg) and struct.unpack_from("<7d", msg, enc.values_offset) == (1.0, -2.0, 3.5, 0.0, 0.0,
                                                                                         0.6, 0.8)
    assert not enc.matches(PoseStampedEncoder("tool").encode(0, (0, 0, 0), (0, 0, 0, 1)))
    assert not enc.matches(msg[:-1]) and not enc.matches(b"\x00\x00" + msg[2:])     # truncated, big-endian
    out = np.empty(7)
    read_doubles(np.frombuffer(msg, np.uint8), enc.values_offset, out, 7)
    decoded = PoseStampedDecoder("world").decode(msg)
    assert out.tolist() == [*decoded.position, *decoded.orientation]


@pytest.mark.parametrize("sec,nanosec,expected", [
    (0, 0, (STAMP_OK, 0)), (2**31 - 1, 999_999_999, (STAMP_OK, (2**31 - 1) * 10**9 + 999_999_999)),
    (-1, 0, (STAMP_REFUSED, 0)), (-2**31, 5, (STAMP_REFUSED, 0)), (5, 10**9, (STAMP_REFUSED, 0)),
    (5, 2**32 - 1, (STAMP_REFUSED, 0))])
def test_the_stamp_is_read_and_refused_as_the_decoders_do(sec, nanosec, expected):
    msg = PoseStampedEncoder("world").encode(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    msg = msg[:4] + struct.pack("<iI", sec, nanosec) + msg[12:]
    assert read_stamp(np.frombuffer(msg, np.uint8)) == expected
    if expected[0] == STAMP_OK:
        assert PoseStampedDecoder("world").decode(msg).stamp_ns == expected[1]
    else:
        with pytest.raises(ValueError, match="header.stamp"):
            PoseStampedDecoder("world").decode(msg)
