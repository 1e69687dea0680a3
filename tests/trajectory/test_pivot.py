"""The pivot point: with a tool offset in force a hexapod's platform turns about the
tool tip (G43 H from the tool table, or any point of the platform by G43.1 X Y Z), as
PI's hexapods and LinuxCNC's tool-centre-point kinematics do. The tip is computed from
each sampled pose with the machine's own pose (its rotation), independently of the
planner's pivot geometry."""

import math

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_trajectory.planner import Limits, plan_validated
from pkm_trajectory.program import gcode_segments
from pkm_trajectory.tool_table import parse_tool_table

LIMITS = Limits((0.1,) * 3 + (0.5,) * 3, (1.0,) * 3 + (5.0,) * 3, (40.0,) * 3 + (200.0,) * 3)


@pytest.fixture(scope="module")
def hexapod():
    return load_machine("genhexkins").model


def tips(machine, samples, offset):
    out = []
    for x in samples.position:
        p, rotation = machine.pose(x)
        out.append(np.asarray(p) - rotation @ np.asarray(offset))
    return np.array(out)


def run(machine, text, tools=None):
    segments = gcode_segments(text, machine.task_space, machine.home, tools=tools)
    return plan_validated(segments, machine, LIMITS, 1000.0, 0.0, 2.0, 50.0)


@pytest.mark.parametrize("setup, offset", [
    ("T1 M6 G43 H1", (0.0, 0.0, 0.05)),                 # the tool's length from the table
    ("G43.1 X10 Y-5 Z30", (0.01, -0.005, 0.03)),        # a pivot anywhere on the platform
])
def test_a_pure_rotation_about_the_tool_tip_keeps_the_tip_within_a_micrometre(hexapod, setup, offset):
    tools = parse_tool_table("T1 P1 Z50 ; 50 mm\n")
    samples = run(hexapod, f"G21 G90\n{setup}\nG1 A5 B-3 C4 F600\nG1 A-4 B2 C0\nM2\n", tools)
    tip = tips(hexapod, samples, offset)
    moved = np.linalg.norm(tip - tip[0], axis=1).max()
    assert moved < 1e-6, moved
    assert np.degrees(samples.position[:, 3]).max() == pytest.approx(5.0)          # the platform did turn
    platform = np.linalg.norm(samples.position[:, :3] - samples.position[0, :3], axis=1).max()
    assert platform > 2e-3, platform                                                # about the tip, not its origin


def test_a_tilt_with_a_translation_moves_the_tip_on_a_straight_line(hexapod):
    samples = run(hexapod, "G21 G90\nG43.1 Z50\nG1 X20 Y-10 A4 B-3 F600\nM2\n")
    tip = tips(hexapod, samples, (0.0, 0.0, 0.05))
    start, end = tip[0], tip[-1]
    assert np.allclose(end - start, [0.02, -0.01, 0.0], atol=1e-9)
    direction = (end - start) / np.linalg.norm(end - start)
    off_line = np.linalg.norm(np.cross(tip - start, direction), axis=1).max()
    assert off_line < 1e-6, off_line
    speed = (np.linalg.norm(np.diff(tip, axis=0), axis=1) / np.diff(samples.time_s)).max()
    assert speed <= 0.010 * 1.001, speed                                            # F600 mm/min at the tip


def test_without_an_offset_the_platform_turns_about_its_origin(hexapod):
    samples = run(hexapod, "G21 G90\nG1 A5 F600\nM2\n")
    assert np.allclose(samples.position[:, :3], samples.position[0, :3])
    assert math.degrees(samples.position[-1, 3]) == pytest.approx(5.0)


def test_a_tool_offset_changed_while_the_platform_is_turned_moves_nothing(hexapod):
    """G43 and G49 at A 30: the next X move goes along X only (the tip is the offset away
    from the spindle along the turned tool)."""
    from pkm_kinematics.task_space import SPATIAL
    tools = parse_tool_table("T1 P1 Z100\n")
    start = [0.0, 0.0, 0.0, math.radians(30.0), 0.0, 0.0]
    lines = [s for s in gcode_segments("G21\nT1 M6\nG43 H1\nG1 X10 F100\nG49\nG1 X20\n", SPATIAL, start,
                                       tools=tools) if hasattr(s, "start")]
    assert [np.round(np.subtract(s.end, s.start)[:3] * 1e3, 9).tolist() for s in lines] == [[10, 0, 0], [10, 0, 0]]
