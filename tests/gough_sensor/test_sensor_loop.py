"""The Gough sensor's loop (GoughSensorLoop.on_true_pose) reads a true pose with the
compiled reading (GoughSensorModel.measure_fields, estimate_into): the same bytes, counts
and errors as the interpreted path it replaced (the model's measure() and estimate(),
pose_components), which this test keeps as its reference, over a motion with noise, a
mis-calibrated sensor, refused poses, readings outside the travel and DKM failures."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from pkm_common.cdr import JointStateEncoder, PoseStampedEncoder, decode_pose_stamped
from pkm_common.poses import pose_components, pose_from_components
from pkm_gough_sensor.metrology import STRUT_NAMES, GoughSensorModel, quantized, quantized_kernel, tool_in_world_kernel
from pkm_gough_sensor.sensor_loop import ACCEPTED_FRAMES, GoughSensorLoop
from pkm_kinematics import load_machine
from pkm_kinematics.rotations import exp_so3, mul3, mv3, rotation_quaternion_floats, rotation_quaternion_kernel

MET = load_machine("mom3").metrology


class Ports:
    def __init__(self):
        self.out = []

    def publish_struts(self, data):
        self.out.append(("struts", bytes(data)))

    def publish_pose(self, data):
        self.out.append(("pose", bytes(data)))

    def error(self, message, values):
        self.out.append(("error", message, repr(values)))


def reference_on_true_pose(model, ports, counts, buf):
    """The loop's reading as it was interpreted (before the compiled reading)."""
    struts, pose = JointStateEncoder(STRUT_NAMES, "gough_base", fields=("position",)), PoseStampedEncoder("world")
    ns = -1
    try:
        msg = decode_pose_stamped(buf, "platform/true_pose")
        ns = msg.stamp_ns
        if msg.frame_id not in ACCEPTED_FRAMES:
            raise ValueError(f"header.frame_id: must be 'world', got {msg.frame_id!r}")
        lengths = model.measure(*pose_from_components(msg.position, msg.orientation))
    except ValueError as exc:
        counts["refused"] += 1
        ports.error(f"true pose refused: {exc}", {"stamp_ns": ns})
        return
    lengths = lengths.tolist()
    ports.publish_struts(struts.encode(ns, position=lengths))
    est_p, est_r, result = model.estimate(lengths)
    if result.converged:
        counts["solved"] += 1
        ports.publish_pose(pose.encode(ns, *pose_components(est_p, est_r)))
    else:
        counts["failed"] += 1
        ports.error(f"DKM failed: {result.reason}", {
            "stamp_ns": ns, "iterations": result.iterations,
            "residual_m": result.residual_m, "lengths_m": lengths})


def true_poses(model, n):
    """A tool motion about the Gough's home with turns of a few mrad, and in it what a
    true_pose topic must refuse or cannot be read."""
    p0, r0 = model.tool_pose(MET.platform.home_position, np.eye(3))
    enc = PoseStampedEncoder("world")
    out = []
    for k in range(n):
        s = k / n
        turn = 2 * math.pi * s
        p = p0 + 0.01 * np.array([math.sin(turn), math.sin(2 * turn), 0.3 * math.cos(turn)])
        r = exp_so3(3e-3 * np.array([math.sin(2 * math.pi * s), math.cos(2 * math.pi * s), s])) @ r0
        position, q = pose_components(p, r)
        buf = enc.encode(1000 + k * 1_000_000, position, q)
        if k % 97 == 13:
            buf = enc.encode(1000 + k * 1_000_000, position, (q[0], q[1], q[2], q[3] * 1.01))   # |q| != 1
        elif k % 97 == 29:
            buf = enc.encode(1000 + k * 1_000_000, (position[0], math.nan, position[2]), q)
        elif k % 97 == 41:
            buf = PoseStampedEncoder("tool").encode(1000 + k * 1_000_000, position, q)       # not world
        elif k % 97 == 53:
            buf = PoseStampedEncoder("").encode(1000 + k * 1_000_000, position, q)           # accepted too
        elif k % 97 == 67:
            buf = enc.encode(1000 + k * 1_000_000, (position[0] + 1.5, position[1], position[2]), q)  # outside
        elif k % 97 == 79:
            buf = buf[:-8]                                                                    # truncated
        elif k % 97 == 83:
            buf = enc.encode(1000 + (k - 1) * 1_000_000, position, q)                         # a repeat
        elif k % 97 == 89:
            buf = buf[:4] + struct.pack("<i", -1) + buf[8:]                                   # before 1970
        elif k % 97 == 91:
            buf = buf[:8] + struct.pack("<I", 1_000_000_000) + buf[12:]                       # nanosec of 1 s
        out.append(buf)
    return out


@pytest.mark.parametrize("noise,calibration", [(0.0, 0.0), (2e-6, 0.0), (1e-6, 5e-5)])
def test_the_compiled_reading_publishes_what_the_interpreted_one_did(noise, calibration):
    model = GoughSensorModel(MET, noise_std_m=noise, seed=7, calibration_error_m=calibration)
    reference = GoughSensorModel(MET, noise_std_m=noise, seed=7, calibration_error_m=calibration)
    ports, expected = Ports(), Ports()
    loop = GoughSensorLoop(model, ports)
    # the usual message is read from its bytes by one kernel (measure_message), the others decoded
    from_bytes = []
    measure_message = model.measure_message
    model.measure_message = lambda *args: from_bytes.append(measure_message(*args)) or from_bytes[-1]
    counts = dict(refused=0, solved=0, failed=0)
    for buf in true_poses(model, 600):
        loop.on_true_pose(buf)
        reference_on_true_pose(reference, expected, counts, buf)
    assert len(ports.out) == len(expected.out)
    for k, (got, want) in enumerate(zip(ports.out, expected.out)):
        assert got == want, (k, got, want)
    assert {k: loop.counts[k] for k in counts} == counts
    read = sum(ns is not None for ns in from_bytes)
    assert read >= 550 and len(from_bytes) - read == sum(k % 97 in (13, 29, 89, 91) for k in range(600)), (
        read, len(from_bytes))
    refused = sum(k % 97 in (13, 29, 41, 79, 89, 91) for k in range(600))
    assert counts["refused"] == refused and counts["failed"] >= 6, counts    # each case was met


def test_a_dkm_failure_resets_the_warm_start_as_the_interpreted_solve_does():
    model, reference = GoughSensorModel(MET), GoughSensorModel(MET)
    good = model.measure(*model.tool_pose(MET.platform.home_position, np.eye(3)))
    pose = np.empty(7)
    for lengths in (good, np.array([0.64] * 5 + [1.07]), good, good + 1e-4, np.array([0.9, 0.9, 2.5, 0.9, 0.9, 0.9])):
        result = model.estimate_into(np.array(lengths, dtype=float), pose)
        p, r, want = reference.estimate(lengths.tolist())
        assert (result is None) == want.converged, (result, want)
        if result is None:
            assert pose.tolist() == [*pose_components(p, r)[0], *pose_components(p, r)[1]]
        else:
            assert (result.reason, result.iterations, result.jacobian_evaluations) == (
                want.reason, want.iterations, want.jacobian_evaluations)
            assert math.isnan(result.residual_m) == math.isnan(want.residual_m)
    with pytest.raises(ValueError, match="strut lengths"):
        model.estimate_into(np.array([0.8] * 5 + [math.nan]), pose)


def test_the_kernels_round_and_convert_as_their_interpreted_forms():
    rng = np.random.default_rng(3)
    res = 1e-6
    # halves to even, and the values around them
    values = np.concatenate([(np.arange(-50, 50) + 0.5) * res, rng.uniform(0.6, 1.1, 2000)])
    assert [quantized_kernel(v, res) for v in values.tolist()] == [quantized(v, res) for v in values.tolist()]
    for _ in range(200):
        r = tuple(exp_so3(rng.uniform(-3.0, 3.0, 3)).ravel().tolist())
        assert rotation_quaternion_kernel(r) == rotation_quaternion_floats(r)
    # the tool in world as GoughSensorModel computed it on floats before its kernel
    for _ in range(200):
        p_bp, p_wb, p_tp = (tuple(rng.uniform(-1.0, 1.0, 3).tolist()) for _ in range(3))
        r_bp, r_wb, r_pt = (tuple(exp_so3(rng.uniform(-3.0, 3.0, 3)).ravel().tolist()) for _ in range(3))
        r_t = mul3(r_wb, mul3(r_bp, r_pt))
        wp, rp = mv3(r_wb, p_bp), mv3(r_t, p_tp)
        want = (p_wb[0] + wp[0] - rp[0], p_wb[1] + wp[1] - rp[1], p_wb[2] + wp[2] - rp[2]), r_t
        assert tool_in_world_kernel(p_bp, r_bp, p_wb, r_wb, r_pt, p_tp) == want
