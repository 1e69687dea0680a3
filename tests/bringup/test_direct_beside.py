"""The Gough's DKM pose solved beside a direct run's loop (pkm_bringup.direct_beside):
a copy of the sensor solving each reading of the recorded batches gives the messages,
in the order, the counts and the log lines the sensor's loop gives when it solves them
itself, failures included. (tests/bringup/test_direct_engine.py: the same over a whole
run, with the run's own ports.)"""

from __future__ import annotations

import copy
import math

import numpy as np

from pkm_bringup.direct_beside import PoseBeside
from pkm_common import topics
from pkm_common.cdr import PoseStampedEncoder
from pkm_common.conversions import diagnostic_bytes
from pkm_common.poses import pose_components
from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_gough_sensor.sensor_loop import GoughSensorLoop
from pkm_kinematics import load_machine
from pkm_recording.tap import StreamTap, read_batch

MET = load_machine("mom3").metrology
NAMESPACE = "/pkm"


def name_of(relative: str) -> str:
    return relative if relative.startswith("/") else f"{NAMESPACE}/{relative}"


class Run:
    """The publications and log lines of a sensor's ports, in order."""

    def __init__(self):
        self.out, self.log, self.tap = [], self, StreamTap()

    def topic(self, relative):
        run = self

        class Topic:
            def publish(self, data):
                run.out.append((name_of(relative), bytes(data)))
                run.tap.add(name_of(relative), topics.CATALOGUE[relative].type, data, len(run.out))
        return Topic()

    def line(self, node, level, text):
        self.out.append(("log", f"[{level}] [{node}]: {text}"))


class Ports:
    """As the direct engine's sensor ports: the readings, the pose, an error logged and
    published as a diagnostic."""

    def __init__(self, run):
        self.run = run
        self.publish_struts = run.topic(topics.METROLOGY_STRUTS).publish
        self.publish_pose = run.topic(topics.METROLOGY_POSE).publish

    def error(self, message, values):
        self.run.log.line("gough_sensor", "ERROR", message)
        self.run.topic(topics.DIAGNOSTICS).publish(diagnostic_bytes(max(int(values.get("stamp_ns", 0)), 0),
                                                                    "gough_sensor: metrology", 2, message, values))


def poses(model, n):
    """A motion about the Gough's home, some poses far enough for readings outside the
    struts' travel (the DKM refuses them)."""
    p0, r0 = model.tool_pose(MET.platform.home_position, np.eye(3))
    enc = PoseStampedEncoder("world")
    for k in range(n):
        turn = 2 * math.pi * k / n
        p = p0 + 0.01 * np.array([math.sin(turn), math.sin(2 * turn), 0.3 * math.cos(turn)])
        if k % 37 == 11:
            p = p + np.array([0.0, 0.0, 0.4])
        yield enc.encode(1000 + k * 1_000_000, *pose_components(p, r0))


def test_the_pose_solved_beside_the_loop_is_the_loop_s_own():
    model = GoughSensorModel(MET, noise_std_m=1e-6, seed=3, calibration_error_m=2e-5)
    # the reference: the loop solves each reading itself
    alone = Run()
    loop = GoughSensorLoop(copy.deepcopy(model), Ports(alone))
    for buf in poses(model, 300):
        loop.on_true_pose(buf)
    # beside: the loop only reads; a copy of it as it was before the first reading solves
    # the batches (of 64 messages: a reading and its pose may fall in different batches)
    run = Run()
    measuring = GoughSensorLoop(copy.deepcopy(model), Ports(run))
    copied = GoughSensorLoop(copy.deepcopy(model), Ports(Run()))     # as forked before the first step
    measuring.solves_pose = False
    beside = PoseBeside(copied, Ports, name_of)
    channels, written = [], []
    for k, buf in enumerate(poses(model, 300)):
        measuring.on_true_pose(buf)
        if k % 64 == 63 or k == 299:
            batch = run.tap.take_payload()
            if batch is not None:
                written += read_batch(beside.apply(batch, lambda name, relative: channels.append(name)))
    assert loop.counts["failed"] >= 5 and loop.counts["solved"] >= 200, loop.counts
    published = [(name, data) for name, data in alone.out if name != "log"]
    assert [(name, data) for name, _, _, data in written] == published
    assert beside.lines == [text for name, text in alone.out if name == "log"] and beside.lines
    summary = beside.summary()
    assert (summary["solved"], summary["failed"], summary["published_pose"]) == (
        loop.counts["solved"], loop.counts["failed"], loop.published["metrology/pose"])
    assert set(channels) == {name_of(topics.METROLOGY_POSE), name_of(topics.DIAGNOSTICS)}
