"""The G-code interpreter's state and the meaning of a line (no rclpy): modal groups,
coordinate systems, tool length, arcs in three planes, canned cycles, spindle and
coolant events. LinuxCNC's G-code reference is the specification ("Order of
Execution": the steps of :meth:`Interpreter.line` run in its order); where this
project differs, README's "G-code compared with LinuxCNC" says so.

Positions: ``tip`` is the controlled point (the tool tip) in machine coordinates
(m; A B C in rad); a program coordinate is ``tip - G5x offset - G92 offset`` (no
rotation of coordinate systems: G10 R is refused). The tool length offset ``tlo``
(a vector, m: (0, 0, L) for G43) is the spindle's offset from the tip: the machine
point is tip + tlo (program.py turns it with the platform where the machine turns).
"""

from __future__ import annotations

import math

from pkm_kinematics.rotations import rotation_from_rpy

from .gcode_expr import Parameters

__all__ = ['Interpreter', 'PLANES']

# plane -> (first axis, second axis, normal axis, offset letters (first, second)); G3 turns positively
# from the first axis towards the second (memo: G18 is (Z, X), its G2 seen from +Y)
PLANES = {17: (0, 1, 2, 'IJ'), 18: (2, 0, 1, 'KI'), 19: (1, 2, 0, 'JK')}
AXES = 'XYZABC'
SYSTEMS = {54.0: 1, 55.0: 2, 56.0: 3, 57.0: 4, 58.0: 5, 59.0: 6, 59.1: 7, 59.2: 8, 59.3: 9}
PECK_CLEARANCE_M = 0.254e-3     # G83: back down to the hole's bottom less 0.010 in / 0.254 mm
ARC_ABS_TOL_M = 1e-6
ARC_REL_TOL = 1e-4
ZERO_RADIUS_M = 1e-9


class Interpreter:
    """The modal state of a program and the moves it makes (``moves``). ``error(word,
    reason)`` raises the caller's GcodeError for the current line."""

    def __init__(self, start, start_angles, tools: dict | None, params: Parameters, make_move, error,
                 turning: bool = False):
        self.tip = list(start) + list(start_angles)           # x y z (m), a b c (rad)
        self.turning = turning              # a platform whose A B C turn the tool offset with it (a hexapod)
        self.tools, self.params = tools, params
        self.make_move, self.error = make_move, error
        self.moves: list = []
        self.unit = 1e-3                    # G21
        self.absolute = True                # G90
        self.arc_absolute = False           # G91.1 (I J K relative to the start)
        self.plane = 17
        self.motion = None                  # 0 1 2 3, or 81 82 83 (a canned cycle), 80
        self.feed = None                    # m/s (G94)
        self.inverse_time = False           # G93
        self.blend = None                   # G61: 0, G64 P: m, None: the node's
        self.system = 1                     # G54
        self.offsets = {k: [0.0] * 6 for k in range(1, 10)}
        self.g92 = [0.0] * 6
        self.g92_saved = [0.0] * 6
        self.tlo = (0.0, 0.0, 0.0)
        self.selected_tool = None           # T
        self.spindle_tool = 0               # after M6 (0: none)
        self.retract_old_z = True           # G98
        self.cycle = {}                     # sticky canned-cycle words (R Z P Q) and the initial level
        self.spindle_rpm = 0.0
        self.spindle_direction = 'stop'     # M3 cw, M4 ccw, M5 stop
        self.coolant = 'off'                # M7 mist, M8 flood, M9 off

    def spindle_on(self) -> bool:
        return self.spindle_direction != 'stop'

    # ------------------------------------------------------------ coordinates
    def offset(self, axis: int) -> float:
        return self.offsets[self.system][axis] + self.g92[axis]

    def program(self) -> list:
        """The current point in program coordinates."""
        return [t - self.offset(k) for k, t in enumerate(self.tip)]

    def value(self, w, axis: int) -> float:
        """A word's value in SI: lengths in the line's unit, angles deg -> rad."""
        return math.radians(w.value) if axis >= 3 else w.value * self.unit

    def target(self, values: dict, machine: bool = False) -> list:
        """The end point (machine coordinates of the tip) of the axis words of a line."""
        out = list(self.tip)
        for k, a in enumerate(AXES):
            if a in values:
                v = self.value(values[a], k)
                if machine:
                    out[k] = v
                elif self.absolute:
                    out[k] = v + self.offset(k)
                else:
                    out[k] = self.tip[k] + v          # exactly (a full circle's end is its start)
        return out

    def sync_parameters(self) -> None:
        """Offsets readable as LinuxCNC's parameters (5211-5216 G92, 5220 the system,
        5221 + 20 (n - 1) + axis the system n), in the program's current unit."""
        p = self.params
        scale = [1.0 / self.unit] * 3 + [180.0 / math.pi] * 3
        for k in range(6):
            p.set(5211 + k, self.g92[k] * scale[k])
            for n in range(1, 10):
                p.set(5201 + 20 * n + k, self.offsets[n][k] * scale[k])
        p.set(5220, float(self.system))

    # ------------------------------------------------------------ output
    def emit(self, kind: str, n: int, target, feed=None, given: str = '', **extra) -> None:
        """A move to ``target`` (the tip, machine coordinates); ``given``: the angle words
        of the line (the move's angles are None for the others, as before)."""
        angles = tuple(target[3 + k] if a in given else None for k, a in enumerate('ABC'))
        self.moves.append(self.make_move(kind, n, tuple(target[:3]), angles, feed, blend_tolerance=self.blend,
                                         tool_offset=self.tlo, **extra))
        self.tip = list(target)

    def event(self, n: int, name: str, **data) -> None:
        self.moves.append(self.make_move('event', n, tuple(self.tip[:3]), (None, None, None), None,
                                         tool_offset=self.tlo, event=(name, tuple(sorted(data.items())))))

    # ------------------------------------------------------------ steps of a line
    def feed_rate(self, values, motion: int | None) -> float | None:
        """The feed of a G1/G2/G3 on this line (m/s); under G93 from F (1/min) and the
        move's length (``None``: computed by the caller)."""
        if self.inverse_time:
            if 'F' not in values:
                self.error(f'G{motion}', 'inverse time feed (G93): F is required on every G1/G2/G3 line')
            return None
        if self.feed is None:
            return None
        return self.feed

    def tool_length(self, n, words, values, code) -> None:
        """G43 H / G43.1 / G49 (step 18): the spindle does not move, the tip is now the
        offset away from it (LinuxCNC: "G43 does not cause any motion"; a later move
        without Z keeps the machine's Z), the offset turned with a turning platform
        (pivot.pivot_pose: the spindle is tip + R t)."""
        before = self.tlo
        self._tool_length(values, code)
        change = [a - b for a, b in zip(self.tlo, before)]
        if self.turning:
            change = (rotation_from_rpy(*self.tip[3:6]) @ change).tolist()
        self.tip[:3] = [t - d for t, d in zip(self.tip[:3], change)]

    def _tool_length(self, values, code) -> None:
        if code == 49.0:
            self.tlo = (0.0, 0.0, 0.0)
            return
        if code == 43.1:
            given = [values[a] for a in 'XYZ' if a in values]
            rotary = next((values[a] for a in 'ABC' if a in values), None)
            if rotary is not None:
                self.error(rotary.text, 'G43.1 takes a tool offset along X Y Z only')
            if not given:
                self.error('G43.1', 'G43.1 needs the offset as axis words (X Y Z)')
            self.tlo = tuple(values[a].value * self.unit if a in values else 0.0 for a in 'XYZ')
            return
        if 'H' in values:
            h = values['H']
            if h.value < 0 or h.value != int(h.value):
                self.error(h.text, 'H must be a tool number (an integer >= 0)')
            number = int(h.value)
        else:
            number = self.spindle_tool
        if number == 0:
            self.tlo = (0.0, 0.0, 0.0)
            return
        if self.tools is None:
            self.error(values['H'].text if 'H' in values else 'G43', 'no tool table: tool length offsets need '
                       "the trajectory node's tool_table")
        if number not in self.tools:
            self.error(values['H'].text if 'H' in values else 'G43',
                       f'tool {number} is not in the tool table (tools: {sorted(self.tools)})')
        tool = self.tools[number]
        self.tlo = tuple(tool.offsets.get(a, 0.0) for a in 'XYZ')

    def set_offsets(self, n, words, values, l_word, p_word) -> None:
        """G10 L2 / L20 P (step 23)."""
        if l_word is None:
            self.error('G10', 'G10 needs L2 or L20 (coordinate system data); tool table edits are not supported')
        if l_word.value not in (2.0, 20.0):
            self.error(l_word.text, 'G10: only L2 and L20 (coordinate systems) are supported')
        if p_word is None:
            self.error(f'G10 {l_word.text}', 'P missing: the coordinate system, 0 (active) or 1-9 (G54-G59.3)')
        if p_word.value not in range(0, 10):
            self.error(p_word.text, 'G10: P must be an integer 0 (active) or 1-9 (G54-G59.3)')
        if 'R' in values and values['R'].value != 0.0:
            self.error(values['R'].text, 'rotation of a coordinate system (G10 R) is not supported')
        system = int(p_word.value) or self.system
        table = self.offsets[system]
        for k, a in enumerate(AXES):
            if a in values:
                v = self.value(values[a], k)
                table[k] = v if l_word.value == 2.0 else self.tip[k] - self.g92[k] - v
        self.sync_parameters()

    def axis_offsets(self, code, values) -> None:
        """G92 / G92.1 / G92.2 / G92.3 (step 23)."""
        if code == 92.0:
            if not any(a in values for a in AXES):
                self.error('G92', 'G92 needs at least one axis word')
            for k, a in enumerate(AXES):
                self.g92[k] = self.tip[k] - self.offsets[self.system][k] - self.value(values[a], k) \
                    if a in values else 0.0
            self.g92_saved = list(self.g92)
        elif code == 92.1:
            self.g92, self.g92_saved = [0.0] * 6, [0.0] * 6
        elif code == 92.2:
            self.g92 = [0.0] * 6
        else:
            self.g92 = list(self.g92_saved)
        self.sync_parameters()

    # ------------------------------------------------------------ arcs
    def arc(self, n, mname, values, motion, feed) -> None:
        """G2/G3 in the active plane, centre (I J K) or radius (R) form, full circles,
        helices (the normal axis moves linearly) and P turns."""
        first, second, normal, letters = PLANES[self.plane]
        wrong = next((c for c in 'IJK' if c in values and c not in letters), None)
        if wrong is not None:
            self.error(values[wrong].text, f'{wrong} is not an offset of the G{self.plane} plane '
                       f'(its offsets: {" ".join(letters)})')
        start = list(self.tip)
        end = self.target(values)
        offsets = [values[c] for c in letters if c in values]
        turns = 1
        if 'P' in values:
            p = values['P']
            if p.value < 1 or p.value != int(p.value):
                self.error(p.text, 'P (turns of an arc) must be an integer >= 1')
            turns = int(p.value)
        if 'R' in values:
            if offsets:
                self.error(values['R'].text, 'an arc has either R or its centre offsets, not both')
            center = self.radius_center(mname, values['R'], start, end, first, second, motion)
        else:
            if not offsets:
                self.error(mname, f'arc without its centre: give {" ".join(letters)} (centre form) or R')
            named = ' '.join(w.text for w in offsets)
            if self.arc_absolute and len(offsets) < 2:
                self.error(f'{mname} {named}', f'G90.1 (absolute centre) needs both {" ".join(letters)}')
            center = list(start)
            for axis, c in ((first, letters[0]), (second, letters[1])):
                if c in values:
                    d = values[c].value * self.unit
                    center[axis] = d + self.offset(axis) if self.arc_absolute else start[axis] + d
            r0 = math.hypot(start[first] - center[first], start[second] - center[second])
            if r0 < ZERO_RADIUS_M:
                self.error(f'{mname} {named}', 'zero arc radius')
            r1 = math.hypot(end[first] - center[first], end[second] - center[second])
            tol = ARC_ABS_TOL_M + ARC_REL_TOL * r0
            if abs(r1 - r0) > tol:
                self.error(f'{mname} {named}', f'end point not on the arc: radius {r0:.9g} m at the start, '
                           f'{r1:.9g} m at the end (differ by {abs(r1 - r0):.3g} m > {tol:.3g} m; '
                           f'{" ".join(letters)} inconsistent with the end point)')
        full = abs(end[first] - start[first]) < ZERO_RADIUS_M and abs(end[second] - start[second]) < ZERO_RADIUS_M
        if full:
            end[first], end[second] = start[first], start[second]
        a0 = math.atan2(start[second] - center[second], start[first] - center[first])
        a1 = math.atan2(end[second] - center[second], end[first] - center[first])
        clockwise = motion == 2
        if full:
            sweep = 2.0 * math.pi
        else:
            sweep = ((a0 - a1) if clockwise else (a1 - a0)) % (2.0 * math.pi)
        sweep += 2.0 * math.pi * (turns - 1)
        sweep = -sweep if clockwise else sweep
        center[normal] = start[normal]
        if self.inverse_time:
            radius = math.hypot(start[first] - center[first], start[second] - center[second])
            length = math.hypot(radius * sweep, end[normal] - start[normal])
            feed = length * values['F'].value / 60.0
        self.emit('arc', n, end, feed, ''.join(a for a in 'ABC' if a in values), center=tuple(center[:3]),
                  clockwise=clockwise, plane=self.plane, sweep=sweep)

    def radius_center(self, mname, r_word, start, end, first, second, motion) -> list:
        """The centre of a radius-form arc: on the chord's left for G3 under 180 deg
        (R > 0), on its right for G2; R < 0 is the arc over 180 deg."""
        r = r_word.value * self.unit
        dx, dy = end[first] - start[first], end[second] - start[second]
        chord = math.hypot(dx, dy)
        if chord < ZERO_RADIUS_M:
            self.error(f'{mname} {r_word.text}', 'a radius-form arc cannot end where it starts (a full circle '
                       'needs the centre form)')
        half = 0.5 * chord
        if abs(r) < half - ARC_ABS_TOL_M:
            self.error(f'{mname} {r_word.text}', f'the radius {abs(r):.6g} m cannot reach the end point '
                       f'{chord:.6g} m away (it needs at least {half:.6g} m)')
        h = math.sqrt(max(r * r - half * half, 0.0))
        side = (1.0 if motion == 3 else -1.0) * (1.0 if r > 0 else -1.0)
        center = list(start)
        center[first] = start[first] + 0.5 * dx - side * h * dy / chord
        center[second] = start[second] + 0.5 * dy + side * h * dx / chord
        return center

    # ------------------------------------------------------------ canned cycles
    def canned_cycle(self, n, code: int, values, repeat) -> None:
        """G81 / G82 / G83 in the XY plane (LinuxCNC "Canned Cycles"): the preliminary
        move to R, then per repeat a rapid over the hole, a rapid to R, the feed to Z
        (G83: in pecks of Q, back to R between them), G82's dwell, the retract to the
        old Z (G98, when above R) or R (G99)."""
        name = f'G{code}'
        if self.plane != 17:
            self.error(name, 'canned cycles are supported in the XY plane (G17) only')
        if self.inverse_time:
            self.error(name, 'canned cycles cannot run under inverse time feed (G93)')
        rotary = next((values[a] for a in 'ABC' if a in values), None)
        if rotary is not None:
            self.error(rotary.text, f'rotary axis words are not allowed in a canned cycle ({name})')
        if self.feed is None:
            self.error(name, 'no feed rate: F must be given before a canned cycle')
        same = self.cycle.get('code') == code
        if not self.cycle:
            self.cycle = {'old_z': self.tip[2]}        # the initial level: Z before this series of cycles
        self.cycle['code'] = code
        z_off = self.offset(2)
        # R and Z sticky as written; under G91 R counts from the initial level and Z from R
        # (LinuxCNC interp_cycles: r = R + initial level, z = r + Z), each line anew
        if 'R' in values:
            self.cycle['r'] = values['R'].value * self.unit
        if 'r' not in self.cycle:
            self.error(name, 'R (the retract plane) is missing')
        r_level = self.cycle['r'] + (z_off if self.absolute else self.cycle['old_z'])
        if 'Z' in values:
            self.cycle['z'] = values['Z'].value * self.unit
        elif not same or 'z' not in self.cycle:
            self.error(name, 'Z (the bottom of the hole) is missing')
        bottom = self.cycle['z'] + (z_off if self.absolute else r_level)
        if r_level < bottom:
            self.error(name, f'the R plane ({(r_level - z_off) / self.unit:g}) is below the bottom Z '
                       f'({(bottom - z_off) / self.unit:g})')
        if code != 82:
            self.cycle.pop('P', None)           # a dwell belongs to G82 (P is refused on G81/G83 lines)
        for letter, needed in (('P', code == 82), ('Q', code == 83)):
            if letter in values:
                w = values[letter]
                if w.value <= 0.0 if letter == 'Q' else w.value < 0.0:
                    self.error(w.text, f'{letter} must be {"> 0" if letter == "Q" else ">= 0"} in {name}')
                self.cycle[letter] = w.value * (self.unit if letter == 'Q' else 1.0)
            elif needed and letter not in self.cycle:
                self.error(name, f'{letter} missing ({"the dwell, s" if letter == "P" else "the peck depth"})')
        clear = self.cycle['old_z'] if self.retract_old_z and self.cycle['old_z'] > r_level else r_level
        if self.tip[2] < r_level:                       # once, whatever L
            self.emit('rapid', n, self.tip[:2] + [r_level] + self.tip[3:])
        hole = list(self.tip)
        for _ in range(repeat):
            for k, a in enumerate('XY'):
                if a in values:
                    v = values[a].value * self.unit
                    hole[k] = (v + self.offset(k)) if self.absolute else hole[k] + v
            self.emit('rapid', n, hole[:2] + [self.tip[2]] + self.tip[3:])
            if self.tip[2] != r_level:
                self.emit('rapid', n, hole[:2] + [r_level] + self.tip[3:])
            self.drill(n, code, r_level, bottom)
            if code == 82 and self.cycle.get('P', 0.0) > 0.0:
                self.moves.append(self.make_move('dwell', n, tuple(self.tip[:3]), (None, None, None), None,
                                                 dwell_s=self.cycle['P'], tool_offset=self.tlo))
            self.emit('rapid', n, hole[:2] + [clear] + self.tip[3:])

    def drill(self, n, code, r_level, bottom) -> None:
        """The feed to the bottom: in one (G81, G82) or in pecks of Q (G83)."""
        here = self.tip[:2]
        rest = self.tip[3:]
        if code != 83:
            self.emit('linear', n, here + [bottom] + rest, self.feed)
            return
        depth = r_level
        while depth > bottom:
            depth = max(depth - self.cycle['Q'], bottom)
            self.emit('linear', n, here + [depth] + rest, self.feed)
            if depth > bottom:
                self.emit('rapid', n, here + [r_level] + rest)
                self.emit('rapid', n, here + [depth + PECK_CLEARANCE_M] + rest)
