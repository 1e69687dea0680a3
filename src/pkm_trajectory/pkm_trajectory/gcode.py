"""G-code reader of the PKM controller: LinuxCNC's G-code as CAM post-processors write
it, turned into moves in SI units.

No rclpy. ``parse_gcode(text)`` returns a list of ``Move``
for the trajectory planner, or raises ``GcodeError`` (a ``ValueError``) whose message
starts with ``line N:`` and names the offending word. Nothing is ignored silently:
every word is either understood or refused.

This module reads a line into words (a word's value may be a number, a parameter, an
expression or a function: ``gcode_expr``) and classifies them by modal group;
``gcode_interp.Interpreter`` gives them their meaning in LinuxCNC's order of execution.
What is supported and where it differs from LinuxCNC: README, "G-code compared with
LinuxCNC". The tool table is LinuxCNC's ``tool.tbl`` (``tool_table``).

Decisions where RS274 dialects differ (documented, tested)
----------------------------------------------------------
- A modal word on a line applies to every number of that line: ``G20 G1 X1 F10``
  reads X and F in inches (LinuxCNC reads F before it switches units).
- ``F`` is converted to m/s when it is read, with the unit of its line. A later
  G20/G21 does not change the physical feed.
- Arcs: an omitted centre offset is 0; no offset and no R is an error. End point equal
  to the start point is a full circle (centre form only). An end radius differing from
  the start radius by more than ``1e-6 m + 1e-4 r`` is refused (LinuxCNC: 0.0283 mm
  and 0.1 %, or 2.83 mm). The A B C (or C) of an arc turn linearly along it.
- ``G4`` cannot share its line with a motion code or axis words; words are refused
  where they mean nothing (I J K off arcs, Q off G83, L off G10 and cycles, H off G43).
- After ``M2``/``M30`` any further word is an error (``after program end``).
- Nested ``(`` inside a comment and ``N`` after the first word are errors (RS274).
- Numbers: optional sign, digits, optional decimal point (``X-.5``, ``X1.``); no
  exponents, no spaces inside a number (``X 1 0`` is an error, ``X 10`` is fine).
- O-words (subroutines, loops, conditionals): ``gcode_flow``; one that is not alone at
  the start of its line is refused.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass

from pkm_kinematics.errors import FieldError

from .gcode_expr import ExprError, Parameters, read_assignment, read_real
from .gcode_flow import MAX_LINES, Flow, o_line
from .gcode_interp import AXES, SYSTEMS, Interpreter

__all__ = ['Move', 'GcodeError', 'parse_gcode', 'MM', 'INCH']

MM = 1e-3       # m per mm (G21)
MAX_MOVES = 1_000_000   # a program's moves, dwells and events (program.MAX_SEGMENTS)
SYSTEM_PARAMETERS = (5161, 5390)     # LinuxCNC's G28/G30, G92 and G54-G59.3 data: read-only here
INCH = 0.0254   # m per inch (G20)

_NUMBER = re.compile(r'[+-]?(?:\d+(?:\.\d*)?|\.\d+)\Z')
_NUMBER_CHARS = frozenset('0123456789.+-')
_FUNCTION = re.compile(r'(?i)(ABS|ACOS|ASIN|ATAN|COS|EXP|FIX|FUP|ROUND|LN|SIN|SQRT|TAN|EXISTS)\s*\[')
_LINE_SPLIT = re.compile(r'\r\n|\n|\r')

# G-codes by modal group (LinuxCNC "Modal Groups"); the group's name is in its errors
_G_GROUPS = {
    'motion code': (0.0, 1.0, 2.0, 3.0, 80.0, 81.0, 82.0, 83.0),
    'non-modal code': (4.0, 10.0, 92.0, 92.1, 92.2, 92.3),
    'plane': (17.0, 18.0, 19.0),
    'unit code': (20.0, 21.0),
    'distance mode': (90.0, 91.0),
    'arc distance mode': (90.1, 91.1),
    'feed mode': (93.0, 94.0),
    'cutter compensation code': (40.0,),
    'tool length code': (43.0, 43.1, 49.0),
    'coordinate system': tuple(SYSTEMS),
    'path control mode': (61.0, 64.0),
    'retract mode': (98.0, 99.0),
}
_G_GROUP = {code: group for group, codes in _G_GROUPS.items() for code in codes}
_M_GROUPS = {'stop': (2.0, 30.0), 'spindle': (3.0, 4.0, 5.0), 'tool change': (6.0,), 'coolant': (7.0, 8.0, 9.0)}
_M_GROUP = {code: group for group, codes in _M_GROUPS.items() for code in codes}
_SUPPORTED_G = ('G0 G1 G2 G3 G4 G10 G17 G18 G19 G20 G21 G40 G43 G43.1 G49 G53 G54-G59.3 G61 G64 G80 G81 G82 '
                'G83 G90 G91 G90.1 G91.1 G92 G92.1 G92.2 G92.3 G93 G94 G98 G99')
_SUPPORTED_M = 'M2 M3 M4 M5 M6 M7 M8 M9 M30'
_VALUE_LETTERS = frozenset('XYZABCIJKRFPQSTHL')
_KIND = {0: 'rapid', 1: 'linear'}
_CHAR_HINTS = {
    '[': 'an expression ([ ]) must be the value of a word or of a parameter setting',
    ']': "']' without a matching '['",
    '/': 'block delete (/) is not supported',
    ')': "')' without a matching '('",
    '%': "'%' is only allowed alone on its line (program delimiter)",
    '*': 'checksums (*) are not supported',
}
_REFUSED_G = {
    (41.0, 42.0, 41.1, 42.1): 'cutter compensation is not supported (the planner follows the programmed path; '
                              'G40 is accepted)',
    (73.0, 76.0, 84.0, 85.0, 86.0, 87.0, 88.0, 89.0): 'this canned cycle is not supported (G81 G82 G83 are)',
    (61.1,): 'exact path mode is not supported (G61, G64 are)',
    (43.2,): 'additive tool length offsets are not supported (G43 H, G43.1, G49 are)',
}


@dataclass(frozen=True)
class Move:
    """One motion, dwell or event of the program, in SI units (m, rad, m/s, s)."""

    kind: str                      # "rapid" (G0), "linear" (G1), "arc" (G2/G3), "dwell" (G4), "event"
    line: int                      # 1-based source line number
    target: tuple                  # absolute end point of the tool tip (x, y, z), machine coordinates, m
    angles: tuple                  # absolute (A, B, C) angles, rad, each None unless the line gave it
    feed: float | None             # m/s for linear/arc; None for rapid/dwell
    center: tuple | None           # arc centre (x, y, z) absolute, m; arcs only
    clockwise: bool | None         # True for G2, False for G3, None otherwise
    dwell_s: float = 0.0           # G4 P, s
    blend_tolerance: float | None = None   # G64 P (m) / G61 (0) in force; None: the node's blend_tolerance_m
    plane: int = 17                # an arc's plane: 17 (XY), 18 (ZX), 19 (YZ)
    sweep: float | None = None     # an arc's signed angle (rad; positive from the plane's first axis to its second)
    tool_offset: tuple = (0.0, 0.0, 0.0)   # the tool length offset in force (G43), m: the spindle is tip + it
    event: tuple | None = None     # an event's (name, ((key, value), ...)): spindle, coolant, tool_change


class GcodeError(ValueError):
    """A G-code program is refused; the message starts with ``line N: ``."""

    def __init__(self, line: int, message: str):
        self.line, self.detail = line, message
        super().__init__(f'line {line}: {message}')

    def __reduce__(self):            # pickled with its fields (a study worker's error reaches its client)
        return type(self), (self.line, self.detail)


@dataclass
class _Word:
    letter: str
    value: float
    text: str        # as written, normalised: upper-case letter + number text ("G01", "X-1.5")


def _strip_comments(raw: str, n: int) -> str:
    """The code of a line with ( ... ) comments replaced by a space and ; comments cut."""
    out = []
    i, size = 0, len(raw)
    while i < size:
        c = raw[i]
        if c == ';':
            break
        if c == '(':
            close = raw.find(')', i + 1)
            if close < 0:
                raise GcodeError(n, "unclosed '(' comment: ')' missing on this line")
            if '(' in raw[i + 1:close]:
                raise GcodeError(n, "nested '(' inside a comment")
            out.append(' ')
            i = close + 1
            continue
        out.append(c)
        i += 1
    return ''.join(out)


def _tokenize(code: str, n: int, params: Parameters) -> tuple[list[_Word], list]:
    """The words of a line and its parameter settings (``#1 = [..]``, applied by the
    caller after the line: LinuxCNC sets parameters after every read of the line). A
    word's value is a number, a parameter, an expression or a function (gcode_expr)."""
    words, settings = [], []
    i, size = 0, len(code)
    while i < size:
        c = code[i]
        if c.isspace():
            i += 1
            continue
        if c == '#':
            try:
                setting, i = read_assignment(code, i, params)
            except ExprError as exc:
                raise GcodeError(n, str(exc)) from None
            settings.append(setting)
            continue
        if not ('A' <= c.upper() <= 'Z' and c.isascii()):
            if c in _NUMBER_CHARS:
                raise GcodeError(n, f"unexpected number text '{c}' with no letter before it "
                                    '(a word is a letter and a number; no spaces inside a number)')
            raise GcodeError(n, f"unexpected character {c!r}: "
                                + _CHAR_HINTS.get(c, 'not part of the supported G-code subset'))
        letter = c.upper()
        i += 1
        while i < size and code[i].isspace():
            i += 1
        if letter == 'O':          # an O-word line is the flow's (gcode_flow); here it is inside a line
            j = i
            while j < size and code[j] in _NUMBER_CHARS:
                j += 1
            raise GcodeError(n, f'O{code[i:j]}: an O-word must begin its line, alone (o100 sub, o101 if [...])')
        if i >= size or not (code[i] in _NUMBER_CHARS or code[i] in '#[' or code[i].isalpha()):
            raise GcodeError(n, f'{letter}: malformed word: a number must follow the letter')
        if code[i].isalpha() and not _FUNCTION.match(code, i):
            raise GcodeError(n, f'{letter}: malformed word: a number must follow the letter')
        j = i
        while j < size and code[j] in _NUMBER_CHARS:
            j += 1
        plain = code[i:j]
        if plain and (j >= size or code[j] not in '#[' and not code[j].isalpha() or code[j] in 'Ee'):
            if not _NUMBER.match(plain):     # a plain number: the strict reader (no exponents, one sign)
                raise GcodeError(n, f'{letter}{plain}: malformed number {plain!r}')
        try:
            value, j = read_real(code, i, params)
        except ExprError as exc:
            raise GcodeError(n, f'{letter}{code[i:i + 30].strip()}: {exc}') from None
        text = code[i:j].strip()
        if not math.isfinite(value):           # 400 digits: a float's range ends near 1.8e308
            raise GcodeError(n, f'{letter}{text[:20]}{"..." if len(text) > 20 else ""}: number out of range '
                                f'({len(text)} characters)')
        words.append(_Word(letter, value, letter + text))
        i = j
    return words, settings


def _check_point(start, name: str) -> tuple:
    try:
        values = tuple(float(v) for v in start)
    except (TypeError, ValueError):
        raise FieldError(name, f'expected 3 finite numbers (x, y, z) in m, got {start!r}') from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise FieldError(name, f'expected 3 finite numbers (x, y, z) in m, got {start!r}')
    return values


def parse_gcode(text: str, start=(0.0, 0.0, 0.0), start_angles=(0.0, 0.0, 0.0), tools: dict | None = None,
                parameters: Parameters | None = None, max_moves: int = MAX_MOVES, turning: bool = False,
                deadline: float | None = None) -> list[Move]:
    """Parse a G-code program into moves in SI units.

    ``start`` is the machine point (m) and ``start_angles`` the A, B, C angles (rad)
    before the first line; ``tools`` the tool table (``tool_table.parse_tool_table``)
    that G43 H reads; ``parameters`` the numbered and named parameters (a fresh set by
    default); a program making more than ``max_moves`` moves, dwells and events (loops,
    repeated cycles) is refused when it gets there, before its moves fill the memory, and
    so is one still running at ``deadline`` (time.monotonic()). ``turning``: A B C turn
    the platform and a tool offset with it (a hexapod; gcode_interp.Interpreter).
    Raises ``GcodeError`` (``line N: <word>: <reason>``) for anything outside what is
    supported."""
    if not isinstance(text, str):
        raise TypeError(f'text: expected str, got {type(text).__name__}')
    pos = _check_point(start, 'start')
    angles = [float(a) for a in start_angles]
    if len(angles) != 3 or not all(math.isfinite(a) for a in angles):
        raise FieldError('start_angles', f'expected 3 finite angles (A, B, C) in rad, got {start_angles!r}')
    params = Parameters() if parameters is None else parameters
    line_no = [0]

    def error(word: str, reason: str):
        raise GcodeError(line_no[0], f'{word}: {reason}')

    made = [0]

    def make_move(kind, n, target, angles, feed, center=None, clockwise=None, **rest):
        made[0] += 1
        if made[0] > max_moves:
            raise GcodeError(n, f'the program makes more than {max_moves} moves (its loops and repeats included)')
        return Move(kind, n, target, angles, feed, center, clockwise, **rest)

    interp = Interpreter(pos, angles, tools, params, make_move, error, turning)
    interp.sync_parameters()
    codes = [_strip_comments(raw, n).strip() for n, raw in enumerate(_LINE_SPLIT.split(text), start=1)]

    def flow_error(index: int, message: str):
        raise GcodeError(index + 1, message)

    flow = Flow(codes, params, flow_error) if any(c[:1] in 'oO' or c[:1] in 'nN' and o_line(c) for c in codes) \
        else None
    ended_at = None      # (line, word text) of M2/M30
    i, run = 0, 0
    while i < len(codes):
        n, code = i + 1, codes[i]
        line_no[0] = n
        run += 1
        if run > MAX_LINES:
            raise GcodeError(n, f'the program has run {MAX_LINES} lines: an endless loop?')
        if deadline is not None and run % 64 == 0 and time.monotonic() > deadline:
            raise GcodeError(n, 'reading the program passed the planning time limit (max_planning_s)')
        if not code or code == '%':
            i += 1
            continue
        if flow is not None and i in flow.lines and ended_at is None:
            i = flow.step(i)
            continue
        words, settings = _tokenize(code, n, params)
        if ended_at is not None:
            first = next((w.text for w in words if w.letter != 'N'), words[0].text if words else '#')
            raise GcodeError(n, f'{first}: after program end ({ended_at[1]} on line {ended_at[0]})')
        end_word = _line(interp, n, words)
        for key, value in settings:           # after every read of the line (LinuxCNC)
            if isinstance(key, int) and SYSTEM_PARAMETERS[0] <= key <= SYSTEM_PARAMETERS[1]:
                raise GcodeError(n, f'#{key}: coordinate system data is read-only here (set it with G10 L2/L20 '
                                    'or G92)')
            params.set(key, value)
        if end_word is not None:
            ended_at = (n, end_word.text)
        i += 1
    return interp.moves


def _classify(n: int, words: list):
    """(values by letter, G-codes by group, M-codes by group, G53 word) of a line."""
    values, g, m, g53 = {}, {}, {}, None
    for k, w in enumerate(words):
        L = w.letter
        if L == 'N':
            if k != 0:
                raise GcodeError(n, f'{w.text}: a line number (N) must be the first word of the line')
            if w.value < 0 or w.value != int(w.value) or '.' in w.text:
                raise GcodeError(n, f'{w.text}: a line number must be a non-negative integer')
            continue
        if L in 'GM' and w.text[1] in '+-':
            raise GcodeError(n, f'{w.text}: unsupported {L}-code (no sign allowed)')
        if L == 'G':
            v = round(w.value, 4)
            if v == 53.0:
                g53 = w
                continue
            group = _G_GROUP.get(v)
            if group is None:
                reason = next((r for codes, r in _REFUSED_G.items() if v in codes), None)
                raise GcodeError(n, f'{w.text}: {reason or f"unsupported G-code (supported: {_SUPPORTED_G})"}')
            if group in g:
                if group == 'non-modal code' and g[group].value == v:
                    raise GcodeError(n, f'{w.text}: G{v:g} given twice on one line')
                raise GcodeError(n, f'{g[group].text} and {w.text}: two {group}s on one line')
            g[group] = w
        elif L == 'M':
            group = _M_GROUP.get(w.value)
            if group is None:
                raise GcodeError(n, f'{w.text}: unsupported M-code (supported: {_SUPPORTED_M})')
            if group in m:
                raise GcodeError(n, f'{m[group].text} and {w.text}: two M-codes of one group ({group}) on one line')
            m[group] = w
        elif L in _VALUE_LETTERS:
            if L in values:
                raise GcodeError(n, f'{w.text}: {L} given twice on one line (first {values[L].text})')
            values[L] = w
        elif L == 'D':
            raise GcodeError(n, f'{w.text}: unsupported word D (cutter compensation is not supported)')
        else:
            raise GcodeError(n, f'{w.text}: unsupported word {L} (supported: G M N {" ".join(sorted(_VALUE_LETTERS))})')
    return values, g, m, g53


def _only_with(n, values, letter: str, allowed: bool, where: str) -> None:
    if letter in values and not allowed:
        raise GcodeError(n, f'{values[letter].text}: {letter} is only allowed {where}')


def _line(it: Interpreter, n: int, words: list):
    """One line, in LinuxCNC's order of execution; returns the M2/M30 word or None."""
    values, g, m, g53 = _classify(n, words)
    gv = {group: round(w.value, 4) for group, w in g.items()}
    non_modal = gv.get('non-modal code')
    motion_word = g.get('motion code')
    axes = [values[a] for a in AXES if a in values]
    # modal settings first: they apply to every number of the line (the module's decision)
    if 'unit code' in gv:
        it.unit = INCH if gv['unit code'] == 20.0 else MM
        it.sync_parameters()                   # the offsets' parameters are in the program's unit
    if 'distance mode' in gv:
        it.absolute = gv['distance mode'] == 90.0
    if 'arc distance mode' in gv:
        it.arc_absolute = gv['arc distance mode'] == 90.1
    motion = it.motion if motion_word is None else int(gv['motion code'])
    uses_axes = non_modal in (10.0, 92.0) or gv.get('tool length code') == 43.1
    if uses_axes and motion_word is not None and axes:
        raise GcodeError(n, f'{g["non-modal code"].text if non_modal else "G43.1"} and {motion_word.text}: '
                            'both would use the axis words of the line')
    cycle = motion in (81, 82, 83)
    arc = motion in (2, 3)
    _only_with(n, values, 'I', arc, 'with G2/G3 (active: ' + (f'G{motion})' if motion is not None else
                                                           'no motion mode)'))
    for letter in 'JK':
        _only_with(n, values, letter, arc, 'with G2/G3')
    _only_with(n, values, 'Q', cycle, 'with G83 (peck depth)')
    _only_with(n, values, 'L', cycle or non_modal == 10.0, 'with G10 or a canned cycle (repeats)')
    _only_with(n, values, 'H', gv.get('tool length code') == 43.0, 'with G43 (the tool of the offset)')
    _only_with(n, values, 'R', arc or cycle or non_modal == 10.0, 'with G2/G3 (radius), G10 or a canned cycle')
    # feed mode, F, S, T, M6, M3-M5, M7-M9 (steps 3-11)
    if 'feed mode' in gv:
        inverse = gv['feed mode'] == 93.0
        if inverse != it.inverse_time:
            it.feed = None                 # a new F is needed after a change of feed mode
        it.inverse_time = inverse
    if 'F' in values:
        w = values['F']
        if not w.value > 0.0:
            raise GcodeError(n, f'{w.text}: feed rate must be > 0')
        if not it.inverse_time:
            it.feed = w.value * it.unit / 60.0
    if 'S' in values:
        if values['S'].value < 0.0:
            raise GcodeError(n, f'{values["S"].text}: spindle speed must be >= 0 rpm')
        it.spindle_rpm = values['S'].value
        if 'spindle' not in m and it.spindle_on():
            it.event(n, 'spindle', direction=it.spindle_direction, rpm=it.spindle_rpm)
    if 'T' in values:
        t = values['T']
        if t.value < 0 or t.value != int(t.value):
            raise GcodeError(n, f'{t.text}: a tool number is an integer >= 0')
        if it.tools is not None and int(t.value) != 0 and int(t.value) not in it.tools:
            raise GcodeError(n, f'{t.text}: tool {int(t.value)} is not in the tool table (tools: {sorted(it.tools)})')
        it.selected_tool = int(t.value)
    if 'tool change' in m:
        if it.selected_tool is None:
            raise GcodeError(n, f'{m["tool change"].text}: no tool selected (T) before the tool change')
        if it.spindle_on():                    # the change stops the spindle (M3 after M6 starts it again)
            it.spindle_direction = 'stop'
            it.event(n, 'spindle', direction='stop', rpm=it.spindle_rpm)
        it.event(n, 'tool_change', tool=it.selected_tool, previous=it.spindle_tool)
        it.spindle_tool = it.selected_tool
    if 'spindle' in m:
        it.spindle_direction = {3.0: 'cw', 4.0: 'ccw', 5.0: 'stop'}[m['spindle'].value]
        it.event(n, 'spindle', direction=it.spindle_direction, rpm=it.spindle_rpm)
    if 'coolant' in m:
        it.coolant = {7.0: 'mist', 8.0: 'flood', 9.0: 'off'}[m['coolant'].value]
        it.event(n, 'coolant', mode=it.coolant)
    # dwell (step 14)
    if non_modal == 4.0:
        dwell = g['non-modal code']
        if motion_word is not None:
            raise GcodeError(n, f'{dwell.text} and {motion_word.text}: a dwell cannot share its line with a motion '
                                'code')
        if axes:
            raise GcodeError(n, f'{axes[0].text}: axis word on a {dwell.text} (dwell) line; put the move on its '
                                'own line')
        if 'P' not in values:
            raise GcodeError(n, f'{dwell.text}: dwell needs P<seconds>')
        if values['P'].value < 0.0:
            raise GcodeError(n, f'{values["P"].text}: dwell time must be >= 0 s')
        it.moves.append(it.make_move('dwell', n, tuple(it.tip[:3]), (None, None, None), None,
                                     dwell_s=values['P'].value, tool_offset=it.tlo))
    # plane, cutter compensation, tool length, coordinate system, path control, retract (steps 15-22)
    if 'plane' in gv:
        it.plane = int(gv['plane'])
    if 'tool length code' in gv:
        it.tool_length(n, words, values, gv['tool length code'])
    if 'coordinate system' in gv:
        it.system = SYSTEMS[gv['coordinate system']]
        it.sync_parameters()
    if 'path control mode' in gv:
        path_word = g['path control mode']
        if gv['path control mode'] == 61.0:
            if 'P' in values:
                raise GcodeError(n, f'{values["P"].text}: P is not allowed with G61 (exact stop)')
            it.blend = 0.0
        elif non_modal == 4.0:
            raise GcodeError(n, f'{g["non-modal code"].text} and {path_word.text}: P would be both a dwell and a '
                                'blending tolerance; put them on separate lines')
        elif 'P' in values:
            if values['P'].value < 0.0:
                raise GcodeError(n, f'{values["P"].text}: G64 blending tolerance must be >= 0')
            it.blend = values['P'].value * it.unit
        else:
            it.blend = None
    if 'retract mode' in gv:
        it.retract_old_z = gv['retract mode'] == 98.0
    p_allowed = non_modal in (4.0, 10.0) or gv.get('path control mode') == 64.0 or arc or motion == 82
    _only_with(n, values, 'P', p_allowed, 'with G4 (dwell), G64 (blending tolerance), G10, G2/G3 (turns) '
                                          'or G82 (dwell)')
    # coordinate system data and axis offsets (step 23)
    if non_modal == 10.0:
        it.set_offsets(n, words, values, values.get('L'), values.get('P'))
    elif non_modal in (92.0, 92.1, 92.2, 92.3):
        it.axis_offsets(non_modal, values)
    # motion (step 24)
    if motion_word is not None:
        it.motion = motion
        if motion == 80:
            it.cycle = {}
            if axes:
                raise GcodeError(n, f'{axes[0].text}: axis words with G80 (cancel the canned cycle)')
    if g53 is not None:
        if motion not in (0, 1) or uses_axes:
            raise GcodeError(n, f'{g53.text}: G53 needs G0 or G1 (machine coordinates apply to a straight move)')
        if not it.absolute:
            raise GcodeError(n, f'{g53.text}: G53 cannot be used with incremental distance (G91)')
    offsets = [values[c] for c in 'IJK' if c in values]
    if (axes or offsets or (arc and 'R' in values)) and not uses_axes:
        _motion(it, n, values, motion, motion_word, g53 is not None, axes + offsets)
    if motion not in (81, 82, 83):
        it.cycle = {}
    if 'stop' in m:                            # M2/M30 end with the spindle stopped and the coolant off (M5, M9)
        if it.spindle_on():
            it.spindle_direction = 'stop'
            it.event(n, 'spindle', direction='stop', rpm=it.spindle_rpm)
        if it.coolant != 'off':
            it.coolant = 'off'
            it.event(n, 'coolant', mode='off')
    return m.get('stop')


def _motion(it: Interpreter, n: int, values: dict, motion, motion_word, machine: bool, given: list) -> None:
    if motion is None or motion == 80:
        mode = 'no motion mode active (give G0, G1, G2 or G3 first)' if motion is None else \
            'no motion mode active: G80 cancelled the canned cycle'
        raise GcodeError(n, f'{given[0].text}: {mode}')
    mname = motion_word.text if motion_word is not None else f'G{motion} (modal)'
    if motion in (81, 82, 83):
        repeat = 1
        if 'L' in values:
            w = values['L']
            if w.value < 1 or w.value != int(w.value):
                raise GcodeError(n, f'{w.text}: L (repeats) must be an integer >= 1')
            repeat = int(w.value)
        it.canned_cycle(n, motion, values, repeat)
        return
    feed = None
    if motion != 0:
        feed = it.feed_rate(values, motion)
        if feed is None and not it.inverse_time:
            raise GcodeError(n, f'{mname}: no feed rate: F must be given before a G1/G2/G3 move')
    if motion in (2, 3):
        it.arc(n, mname, values, motion, feed)
        return
    target = it.target(values, machine)
    if it.inverse_time and motion == 1:
        length = math.dist(target[:3], it.tip[:3])
        if length == 0.0:
            raise GcodeError(n, f'{mname}: inverse time feed (G93) on a move without translation is not supported')
        feed = length * values['F'].value / 60.0
    it.emit(_KIND[motion], n, target, feed, ''.join(a for a in 'ABC' if a in values))
