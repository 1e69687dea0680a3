"""What gough_sensor_node and laser_tracker_node do with each true pose, without rclpy:
read it from its bytes (pkm_common.cdr), measure it, hand the readings' bytes to
``ports``. The nodes implement the ports with their publishers and diagnostics; the
direct engine (pkm_bringup.direct) with its wiring. Their parameters are declared on
a node, or on a pkm_common.params.ParameterValues (the same checks), by
``declare_gough_sensor`` / ``declare_laser_tracker``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pkm_common.cdr import JointStateEncoder, PoseStampedDecoder, PoseStampedEncoder, decode_pose_stamped
from pkm_common.params import ParameterError, declare_float, declare_float_list, declare_int, declare_str
from pkm_common.poses import pose_from_components
from pkm_gough_sensor.laser import MAX_SIGMA_M, LaserTracker
from pkm_gough_sensor.metrology import MAX_RESOLUTION_M, STRUT_NAMES, GoughSensorModel
from pkm_kinematics import load_machine, machine_names

__all__ = ["ACCEPTED_FRAMES", "GoughSensorLoop", "GoughSensorSettings", "LaserLoop", "LaserTrackerSettings",
           "SensorPorts", "declare_gough_sensor", "declare_laser_tracker"]

ACCEPTED_FRAMES = ("world", "")
IDENTITY = (0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class GoughSensorSettings:
    machine: str
    model: GoughSensorModel
    noise_std_m: float
    seed: int
    calibration_error_m: float
    diagnostics_period_s: float
    summary_path: str


def _has_metrology(name: str) -> bool:
    try:
        return load_machine(name).metrology is not None
    except ValueError:
        return False


def declare_gough_sensor(node) -> GoughSensorSettings:
    """gough_sensor's parameters (a bad one raises ParameterError naming it)."""
    machine = declare_str(node, "machine", "mom3", "machine file with a metrology section", choices=machine_names())
    noise = declare_float(node, "noise_std_m", 0.0, 0.0, 1e-3, "std of the Gaussian noise on each strut reading",
                          unit="m")
    seed = declare_int(node, "seed", 0, 0, 2**31 - 1, "seeds the calibration error and the noise")
    calibration = declare_float(node, "calibration_error_m", 0.0, 0.0, 0.01,
                                "std of the per-axis error of the true joint centres", unit="m")
    resolution = declare_float(node, "resolution_m", 0.0, 0.0, MAX_RESOLUTION_M,
                               "scale resolution; 0: the machine file's encoder_resolution", unit="m")
    period = declare_float(node, "diagnostics_period_s", 1.0, 0.01, 60.0, "period of the summary diagnostic",
                           unit="s")
    summary_path = declare_str(node, "summary_path", "", "write a JSON summary here at exit", allow_empty=True)
    config = load_machine(machine)
    if config.metrology is None:
        with_metrology = [n for n in machine_names() if _has_metrology(n)]
        raise ParameterError("machine", f"must name a machine with a metrology section, one of "
                             f"{with_metrology}; {machine!r} has none")
    model = GoughSensorModel(config.metrology, noise, seed, calibration, resolution or None)
    return GoughSensorSettings(machine, model, noise, seed, calibration, period, summary_path)


class SensorPorts(Protocol):
    def publish_struts(self, data: bytes) -> None:
        """metrology/struts (tapped for the recorder)."""

    def publish_pose(self, data: bytes) -> None:
        """metrology/pose (tapped)."""

    def error(self, message: str, values: dict) -> None:
        """A refused true pose or a failed DKM (the node's ERROR diagnostic, rate-limited)."""


def _true_pose(msg):
    """The pose of a decoded platform/true_pose; ValueError names what is wrong."""
    if msg.frame_id not in ACCEPTED_FRAMES:
        raise ValueError(f"header.frame_id: must be 'world', got {msg.frame_id!r}")
    return pose_from_components(msg.position, msg.orientation)


class GoughSensorLoop:
    """The Gough platform's readings of each true pose (MoM3 §4.3) and its DKM pose (§6.3)."""

    def __init__(self, model: GoughSensorModel, ports: SensorPorts):
        self.model, self.ports = model, ports
        self.counts = dict(received=0, measured=0, solved=0, failed=0, refused=0)
        self.published = {"metrology/pose": 0, "metrology/struts": 0}   # distinct stamps
        self._last_stamp_ns = -1
        self._struts_encoder = JointStateEncoder(STRUT_NAMES, "gough_base", fields=("position",))
        self._pose_encoder = PoseStampedEncoder("world")
        self._pose_decoder = PoseStampedDecoder("world", "platform/true_pose")
        # the compiled reading's arrays (GoughSensorModel.measure_fields, estimate_into)
        self._fields, self._lengths, self._pose = np.empty(7), np.empty(6), np.empty(7)
        # a world-frame true pose's bytes (the layout of _pose_encoder's messages) straight to the
        # struts' (GoughSensorModel.measure_message)
        self._struts_msg = np.frombuffer(self._struts_encoder.template(), np.uint8).copy()
        self._struts_at = self._struts_encoder.offsets["position"]
        # False: a shell whose metrology/pose nobody reads (a direct run without a
        # recording whose controller feeds back the struts, pkm_bringup.direct): the DKM is
        # not solved (its summary says so: dkm_run)
        self.solves_pose = True

    def on_true_pose(self, buf: bytes) -> None:
        self.counts["received"] += 1
        if self._pose_encoder.matches(buf):        # the usual message: read and written by one kernel
            ns = self.model.measure_message(np.frombuffer(buf, np.uint8), self._pose_encoder.values_offset,
                                            self._fields, self._lengths, self._struts_msg, self._struts_at)
            if ns is not None:
                self._measured(ns, self._lengths, self._struts_msg.tobytes())
                return
        ns = -1                                    # else decoded: a refusal named
        try:
            msg = self._pose_decoder.decode(buf)
            ns = msg.stamp_ns
            if msg.frame_id not in ACCEPTED_FRAMES:
                _true_pose(msg)                    # raises, naming the frame
            fields = self._fields
            fields[:3], fields[3:] = msg.position, msg.orientation
            lengths = self._lengths
            if not self.model.measure_fields(fields, lengths):
                lengths = self.model.measure(*_true_pose(msg))      # raises what the compiled one refused
        except ValueError as exc:
            self.counts["refused"] += 1
            self.ports.error(f"true pose refused: {exc}", {"stamp_ns": ns})
            return
        self._measured(ns, lengths, self._struts_encoder.encode(ns, position=lengths.tolist()))

    def _measured(self, ns: int, lengths: np.ndarray, struts: bytes) -> None:
        """The readings ``lengths`` of the true pose stamped ``ns`` (``struts``: their
        message) published, then the DKM's pose."""
        self.counts["measured"] += 1
        published = self.published
        new_step = ns != self._last_stamp_ns      # counted once per step (not the discovery repeats)
        self._last_stamp_ns = ns
        # the readings first: a sensor-space controller waits for them, and the DKM
        # is then off its critical path; a measured-space one waits for the pose
        self.ports.publish_struts(struts)
        published["metrology/struts"] += new_step
        if self.solves_pose:
            self.solve_pose(ns, lengths, new_step)

    def solve_pose(self, ns: int, lengths: np.ndarray, new_step: bool) -> None:
        """The DKM pose of the readings ``lengths`` (stamped ``ns``; ``new_step``: not a
        repeat of the last stamp) published, or its failure reported. A direct run has
        it solved beside its loop, where the loop does not read the pose
        (pkm_bringup.direct_beside), by a copy of this sensor: the same poses in turn."""
        published = self.published
        result = self.model.estimate_into(lengths, self._pose)
        if result is None:
            published["metrology/pose"] += new_step
            self.counts["solved"] += 1
            pose = self._pose.tolist()
            self.ports.publish_pose(self._pose_encoder.encode(ns, pose[:3], pose[3:]))
        else:
            self.counts["failed"] += 1
            self.ports.error(f"DKM failed: {result.reason}", {
                "stamp_ns": ns, "iterations": result.iterations,
                "residual_m": result.residual_m, "lengths_m": lengths.tolist()})

    def summary(self) -> dict:
        return {**self.counts, "dkm_run": self.solves_pose, "published": self.published}


@dataclass(frozen=True)
class LaserTrackerSettings:
    model: LaserTracker
    tool: list
    sigma_m: float
    seed: int
    frame_position: list
    frame_rpy_deg: list
    summary_path: str


def declare_laser_tracker(node) -> LaserTrackerSettings:
    """laser_tracker's parameters (a bad one raises ParameterError naming it)."""
    tool = declare_float_list(node, "tool", [0.0, 0.0, 0.0], "the point measured, platform frame", length=3,
                              lo=-10.0, hi=10.0, unit="m")
    sigma = declare_float(node, "sigma_m", 2e-6, 0.0, MAX_SIGMA_M, "the noise's std per axis", unit="m")
    seed = declare_int(node, "seed", 0, 0, 2**31 - 1, "seeds the noise")
    position = declare_float_list(node, "frame_position", [0.0, 0.0, 0.0], "the tracker's frame in the world",
                                  length=3, lo=-100.0, hi=100.0, unit="m")
    rpy = declare_float_list(node, "frame_rpy_deg", [0.0, 0.0, 0.0], "the tracker frame's roll, pitch, yaw",
                             length=3, lo=-360.0, hi=360.0, unit="deg")
    summary_path = declare_str(node, "summary_path", "", "write a JSON summary here at exit", allow_empty=True)
    return LaserTrackerSettings(LaserTracker(tool, sigma, seed, position, rpy), tool, sigma, seed, position, rpy,
                                summary_path)


class LaserLoop:
    """A laser tracker's reading of the tool point of each true pose (instrument/laser).
    ``publish``: the reading's bytes; ``log_error``: a refused true pose."""

    def __init__(self, model: LaserTracker, publish, log_error, topic: str):
        self.model, self.publish, self.log_error = model, publish, log_error
        self.counts = dict(received=0, refused=0)
        self.published = {topic: 0}
        self.topic = topic
        self._last_stamp_ns = -1
        self._encoder = PoseStampedEncoder("laser_tracker")

    def on_true_pose(self, buf: bytes) -> None:
        self.counts["received"] += 1
        try:
            msg = decode_pose_stamped(buf, "platform/true_pose")
            ns = msg.stamp_ns
            position, rotation = _true_pose(msg)
        except ValueError as exc:
            self.counts["refused"] += 1
            self.log_error(f"true pose refused: {exc}")
            return
        point = self.model.measure(position, rotation)
        self.publish(self._encoder.encode(ns, tuple(point.tolist()), IDENTITY))
        self.published[self.topic] += ns != self._last_stamp_ns
        self._last_stamp_ns = ns

    def summary(self) -> dict:
        return {**self.counts, "published": self.published}
