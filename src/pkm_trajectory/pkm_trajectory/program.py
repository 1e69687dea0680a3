"""G-code moves -> planner segments in the machine's task coordinates, with the
Sliding Star "Trajectory Speed, size Adjustment" and "Trajectory Repeater" (§4):
feed override 0-200 %, size scaling about the program start, repetition.

The feed override scales programmed feeds (G1/G2/G3) only, as on LinuxCNC: rapids
(G0) and rotation-only moves run at the axis limits whatever the override.

Axes: the machine's task space (``pkm_kinematics.task_space``) names the G-code word of
each task coordinate: X Y C (x, y, theta) for a planar machine (ARCHI, Sliding Star),
X Y Z for a machine that positions a point (the Delta, the Orthoglide), X Y Z A B C for
a hexapod. A word the machine has no coordinate for is refused with its line. The
program's coordinates are the tool tip's, work offsets applied by the interpreter
(gcode_interp); a tool length offset is added here (the spindle is the tip plus it).
"""

from __future__ import annotations

import json
import math

import numpy as np

from pkm_kinematics.errors import FieldError
from pkm_kinematics.rotations import rotation_from_rpy
from pkm_kinematics.task_space import TaskSpace

from .gcode import Move, parse_gcode
from .pivot import PivotLine, tip_of_pose
from .planner import Arc, Dwell, Line

FEED_OVERRIDE_RANGE = (0.0, 2.0)     # (exclusive, inclusive): 0-200 %, 0 does not plan
_POINT = {"X": 0, "Y": 1, "Z": 2}    # a move's target (x, y, z)
_ANGLE = {"A": 0, "B": 1, "C": 2}    # a move's angles (A, B, C)


MAX_SEGMENTS = 1_000_000     # a program's segments, repeats included (trajectory_node's max_segments is below)


def program_segments(moves: list[Move], space: TaskSpace, start_pose, feed_override: float = 1.0,
                     scale: float = 1.0, repeat: int = 1) -> list:
    """Segments of a parsed program starting at ``start_pose`` (task coordinates of ``space``)."""
    lo, hi = FEED_OVERRIDE_RANGE
    if not lo < feed_override <= hi:
        raise FieldError("feed_override", f"must be in (0, 2] (0-200 %), got {feed_override}")
    if not scale > 0.0 or not math.isfinite(scale):
        raise FieldError("scale", f"must be a positive number, got {scale}")
    if not (isinstance(repeat, int) and repeat >= 1):
        raise FieldError("repeat", f"must be an integer >= 1, got {repeat}")
    origin = [float(v) for v in start_pose]
    if len(origin) != space.dof:
        raise FieldError("start_pose", f"expected {space.dof} task coordinates ({space.describe()}), got {origin}")
    missing = "".join(w for w in "XYZABC" if w not in space.words)

    def refuse_missing(move: Move) -> None:
        for word in missing:
            if word == "Z":
                given = abs(move.target[2]) > 1e-12            # a machine without Z starts at z = 0
            else:
                given = move.angles[_ANGLE[word]] is not None
            if given:
                value = f" (Z{move.target[2] / 1e-3:g} mm)" if word == "Z" else ""
                raise ValueError(f"line {move.line}: this machine has no {word} axis{value}: its task "
                                 f"coordinates are {space.describe()} (G-code {' '.join(space.words)})")

    turns = space.dof == 6                  # the platform turns: a tool offset turns with it (the pivot)

    def spindle_offset(move: Move, pose) -> tuple:
        """The spindle (the pose) is the tip plus the tool offset, turned with the platform
        (pivot.pivot_pose)."""
        if turns and any(move.tool_offset):
            return tuple((rotation_from_rpy(*pose[3:6]) @ np.asarray(move.tool_offset, dtype=float)).tolist())
        return move.tool_offset

    def to_task(move: Move, previous):
        refuse_missing(move)
        point = []
        for i, word in enumerate(space.words):
            if word in _POINT:
                point.append(move.target[_POINT[word]])
            else:
                angle = move.angles[_ANGLE[word]]
                point.append(previous[i] if angle is None else angle)
        offset = spindle_offset(move, point)
        for i, word in enumerate(space.words[:space.translation_axes]):
            point[i] += offset[_POINT[word]]
        # size adjustment about the program start (translation only)
        for i in range(space.translation_axes):
            point[i] = origin[i] + scale * (point[i] - origin[i])
        return point

    def pivot(move: Move, pose, target, speed):
        """A move that turns the platform with a tool offset: about the tip (pivot.PivotLine)."""
        if move.kind == "arc":
            raise ValueError(f"line {move.line}: an arc that turns the platform with a tool offset in force is not "
                             "supported (turn on a straight move, or G49 first)")
        if scale != 1.0:
            raise ValueError(f"line {move.line}: size scaling of a move about the tool tip is not supported")
        tip_start = tip_of_pose(pose, move.tool_offset)
        return PivotLine(tuple(tip_start.tolist()), tuple(move.target), tuple(pose[3:6]), tuple(target[3:6]),
                         tuple(move.tool_offset), speed, line=move.line)

    def plane_axes(move: Move) -> tuple:
        first, second = {17: "XY", 18: "ZX", 19: "YZ"}[move.plane]
        missing = [w for w in (first, second) if w not in space.words]
        if missing:
            raise ValueError(f"line {move.line}: an arc in the G{move.plane} plane needs {missing[0]}: this "
                             f"machine's task coordinates are {space.describe()}")
        return space.words.index(first), space.words.index(second)

    segments, pose = [], list(origin)
    for move in moves:
        if move.kind in ("dwell", "event"):
            segments.append(Dwell(tuple(pose), move.dwell_s, line=move.line, event=move.event))
            continue
        target = to_task(move, pose)
        speed = None if move.feed is None else move.feed * feed_override
        if turns and any(move.tool_offset) and target[3:] != pose[3:]:
            segments.append(pivot(move, pose, target, speed))
        elif move.kind in ("rapid", "linear"):
            if target != pose:
                segments.append(Line(tuple(pose), tuple(target), speed, move.blend_tolerance, line=move.line))
        else:  # an arc in its plane about the (scaled) centre
            i, j = plane_axes(move)
            offset = spindle_offset(move, target)
            centre = [move.center[_POINT[space.words[k]]] + offset[_POINT[space.words[k]]] for k in (i, j)]
            centre = [origin[k] + scale * (c - origin[k]) for k, c in zip((i, j), centre)]
            rest = tuple(target[k] for k in range(space.dof) if k not in (i, j))
            segments.append(Arc(tuple(pose), tuple(centre), move.sweep, rest, speed, line=move.line, axes=(i, j)))
        pose = target            # the programmed point (an arc's computed end differs by ~1e-16)
    if len(segments) * repeat > MAX_SEGMENTS:       # before the list is made (a 1 MB program x 10,000)
        raise FieldError("repeat", f"{len(segments)} segments x {repeat} exceed {MAX_SEGMENTS} segments")
    if repeat > 1:
        if max(abs(a - b) for a, b in zip(pose, origin)) > 1e-9:
            raise FieldError("repeat", f"the program ends at {pose}, not at its start {origin}: "
                                       "it cannot be repeated")
        segments = segments * repeat
    return segments


def gcode_segments(text: str, space: TaskSpace, start_pose, tools: dict | None = None,
                   max_moves: int = MAX_SEGMENTS, deadline: float | None = None, **kwargs) -> list:
    """Parse ``text`` from ``start_pose`` (task coordinates of ``space``) with the tool
    table ``tools`` (tool_table.parse_tool_table) and return its segments (see
    program_segments); more than ``max_moves`` moves, or reading past ``deadline``
    (time.monotonic()), are refused while it is read."""
    start = dict(zip(space.words, (float(v) for v in start_pose)))
    moves = parse_gcode(text, start=tuple(start.get(w, 0.0) for w in "XYZ"),
                        start_angles=tuple(start.get(w, 0.0) for w in "ABC"), tools=tools, max_moves=max_moves,
                        turning=space.dof == 6, deadline=deadline)
    return program_segments(moves, space, start_pose, **kwargs)


def program_events_text(stamp_ns: int, events: list) -> str:
    """The ``program/events`` record of a trajectory (JSON): its header stamp (the one the
    controller's verdict names) and each event at its time from the trajectory's start
    (planner.Samples.events), e.g. {"t_s": 1.2, "line": 7, "name": "spindle",
    "direction": "cw", "rpm": 12000.0}. A spindle drive follows them from the moment the
    controller starts the trajectory (its "trajectory" event)."""
    return json.dumps({"stamp_ns": int(stamp_ns), "events": [
        {"t_s": round(float(t), 9), "line": line, "name": name, **dict(data)} for t, line, (name, data) in events]})
