"""G-code moves -> planner segments in the machine's task coordinates, with the
Sliding Star "Trajectory Speed, size Adjustment" and "Trajectory Repeater" (§4):
feed override 0-200 %, size scaling about the program start, repetition.

The feed override scales programmed feeds (G1/G2/G3) only, as on LinuxCNC: rapids
(G0) and rotation-only moves run at the axis limits whatever the override.

Axes: a planar machine (ARCHI, Sliding Star) takes X, Y and the C angle as
(x, y, theta) and refuses Z; a translational machine takes X, Y, Z and refuses C.
The program's coordinates are machine coordinates (the work offset is the caller's).
"""

from __future__ import annotations

import math

from .gcode import Move, parse_gcode
from .planner import Arc, Dwell, Line

FEED_OVERRIDE_RANGE = (0.0, 2.0)     # (exclusive, inclusive): 0-200 %, 0 does not plan


def program_segments(moves: list[Move], planar: bool, start_pose, feed_override: float = 1.0,
                     scale: float = 1.0, repeat: int = 1) -> list:
    """Segments of a parsed program starting at ``start_pose`` (x, y, theta | z)."""
    lo, hi = FEED_OVERRIDE_RANGE
    if not lo < feed_override <= hi:
        raise ValueError(f"feed_override: must be in (0, 2] (0-200 %), got {feed_override}")
    if not scale > 0.0 or not math.isfinite(scale):
        raise ValueError(f"scale: must be a positive number, got {scale}")
    if not (isinstance(repeat, int) and repeat >= 1):
        raise ValueError(f"repeat: must be an integer >= 1, got {repeat}")
    origin = [float(v) for v in start_pose]

    def to_task(move: Move, previous):
        x, y, z = move.target
        if planar:
            if abs(z) > 1e-12:
                raise ValueError(f"line {move.line}: a planar machine has no Z axis (Z{z / 1e-3:g} mm)")
            third = previous[2] if move.rotation is None else move.rotation
        else:
            if move.rotation is not None:
                raise ValueError(f"line {move.line}: a translational machine has no C axis")
            third = z
        point = [x, y, third]
        # size adjustment about the program start (translation only)
        for i in range(2 if planar else 3):
            point[i] = origin[i] + scale * (point[i] - origin[i])
        return point

    segments, pose = [], list(origin)
    for move in moves:
        if move.kind == "dwell":
            segments.append(Dwell(tuple(pose), move.dwell_s))
            continue
        target = to_task(move, pose)
        speed = None if move.feed is None else move.feed * feed_override
        if move.kind in ("rapid", "linear"):
            if target != pose:
                segments.append(Line(tuple(pose), tuple(target), speed, move.blend_tolerance))
        else:  # arc in the XY plane about the (scaled) centre
            cx = origin[0] + scale * (move.center[0] - origin[0])
            cy = origin[1] + scale * (move.center[1] - origin[1])
            if target[0] == pose[0] and target[1] == pose[1]:
                # a full circle: decided on the programmed points, never on angles that
                # round-off can make 2 pi apart or equal
                sweep = -2.0 * math.pi if move.clockwise else 2.0 * math.pi
            else:
                a0 = math.atan2(pose[1] - cy, pose[0] - cx)
                a1 = math.atan2(target[1] - cy, target[0] - cx)
                if move.clockwise:
                    sweep = -((a0 - a1) % (2.0 * math.pi))
                else:
                    sweep = (a1 - a0) % (2.0 * math.pi)
            segments.append(Arc(tuple(pose), (cx, cy), sweep, target[2], speed))
        pose = target            # the programmed point (an arc's computed end differs by ~1e-16)
    if repeat > 1:
        if max(abs(a - b) for a, b in zip(pose, origin)) > 1e-9:
            raise ValueError(f"repeat: the program ends at {pose}, not at its start {origin}: "
                             "it cannot be repeated")
        segments = segments * repeat
    return segments


def gcode_segments(text: str, planar: bool, start_pose, **kwargs) -> list:
    """Parse ``text`` from ``start_pose`` and return its segments (see program_segments)."""
    start = [float(v) for v in start_pose]
    if planar:
        moves = parse_gcode(text, start=(start[0], start[1], 0.0), start_rotation=start[2])
    else:
        moves = parse_gcode(text, start=tuple(start))
    return program_segments(moves, planar, start, **kwargs)
