"""G-code parser of the PKM controller: an RS274 subset turned into moves in SI units.

Pure Python (no rclpy, no numpy). ``parse_gcode(text)`` returns a list of ``Move``
for the trajectory planner, or raises ``GcodeError`` (a ``ValueError``) whose message
starts with ``line N:`` and names the offending word. Nothing is ignored silently:
every word is either understood or refused.

Supported subset
----------------
- ``G0`` rapid, ``G1`` linear, ``G2``/``G3`` arcs in the XY plane (centre form, ``I``
  ``J`` relative to the start point, in the current length unit, whatever G90/G91),
  ``G4 P<seconds>`` dwell, ``G17`` (XY plane, the only one), ``G20`` inch, ``G21`` mm
  (default), ``G90`` absolute (default), ``G91`` incremental, ``F`` feed in units per
  minute (modal, > 0), ``X Y Z`` coordinates, ``A B C`` rotations about x, y, z in
  degrees (absolute under G90, incremental under G91; which of them a machine has is
  its task space's business, ``pkm_trajectory.program``), ``M2``/``M30`` program end, ``N`` line
  numbers (first word only, ignored), comments ``( ... )`` and after ``;``, ``%``
  delimiter lines, blank lines.
- Path control (LinuxCNC): ``G64 P<tolerance>`` blends the corners between line moves
  within the tolerance (in the line's length unit), ``G64`` alone with the trajectory
  node's ``blend_tolerance_m``, ``G61`` stops exactly at every corner. Modal; each move
  carries the mode in force (``Move.blend_tolerance``: m, 0 for exact stop, None for
  the node's setting, also before any G61/G64). ``G40`` (cutter compensation off, the
  only state here) is accepted and does nothing; ``G64 Q`` (naive CAM tolerance),
  ``G61.1`` and cutter compensation (``G41``/``G42``) are refused.
- Motion is modal: a line with axis words (X Y Z A B C, or I J under G2/G3) and no motion
  code repeats the last of G0/G1/G2/G3. A motion code without axis words only sets
  the mode (``G1 F600``).

Decisions where RS274 dialects differ (documented, tested)
----------------------------------------------------------
- A modal word on a line applies to every number of that line: ``G20 G1 X1 F10``
  reads X and F in inches.
- ``F`` is converted to m/s when it is read, with the unit of its line. A later
  G20/G21 does not change the physical feed (the number is not re-read in the new
  unit).
- Arcs: one of ``I``/``J`` may be omitted (it is 0, as in RS274/LinuxCNC); both
  omitted is an error. End point equal to the start point is a full circle. A line
  under G2/G3 with only ``I``/``J`` is such a full circle.
- ``G4`` cannot share its line with a motion code or axis words (a dwell line does not
  move); ``P`` and ``I``/``J`` are refused where they mean nothing.
- After ``M2``/``M30`` any further word is an error (``after program end``); blank,
  comment and ``%`` lines are allowed. Words on the M2/M30 line itself run first.
- Nested ``(`` inside a comment and ``N`` after the first word are errors (RS274).
- A motion to the current point is still returned as a move; the planner decides.
- Numbers: optional sign, digits, optional decimal point (``X-.5``, ``X1.``); no
  exponents, no spaces inside a number (``X 1 0`` is an error, ``X 10`` is fine).

Tolerances: an arc whose end radius differs from its start radius by more than
``1e-6 m + 1e-4 r`` is refused; a radius below 1 nm is zero; a Z change beyond
1 nm on an arc is a helix (refused).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from pkm_kinematics.errors import FieldError

__all__ = ['Move', 'GcodeError', 'parse_gcode', 'MM', 'INCH']

MM = 1e-3       # m per mm (G21)
INCH = 0.0254   # m per inch (G20)

ARC_ABS_TOL_M = 1e-6
ARC_REL_TOL = 1e-4
ZERO_RADIUS_M = 1e-9
HELIX_TOL_M = 1e-9

_NUMBER = re.compile(r'[+-]?(?:\d+(?:\.\d*)?|\.\d+)\Z')
_NUMBER_CHARS = frozenset('0123456789.+-')
_LINE_SPLIT = re.compile(r'\r\n|\n|\r')

_SUPPORTED_G = 'G0 G1 G2 G3 G4 G17 G20 G21 G40 G61 G64 G90 G91'
_MOTION = {0.0: 0, 1.0: 1, 2.0: 2, 3.0: 3}
_KIND = {0: 'rapid', 1: 'linear', 2: 'arc', 3: 'arc'}
_VALUE_LETTERS = frozenset('XYZABCIJFP')
_ANGLES = 'ABC'
_CHAR_HINTS = {
    '#': 'parameters (#) are not supported',
    '[': 'expressions ([ ]) are not supported',
    ']': 'expressions ([ ]) are not supported',
    '/': 'block delete (/) is not supported',
    ')': "')' without a matching '('",
    '%': "'%' is only allowed alone on its line (program delimiter)",
    '*': 'checksums (*) are not supported',
}


@dataclass(frozen=True)
class Move:
    """One motion or dwell of the program, in SI units (m, rad, m/s, s)."""

    kind: str                      # "rapid" (G0), "linear" (G1), "arc" (G2/G3), "dwell" (G4)
    line: int                      # 1-based source line number
    target: tuple                  # absolute end point (x, y, z), m; dwell: the current point
    angles: tuple                  # absolute (A, B, C) angles, rad, each None unless the line gave it
    feed: float | None             # m/s for linear/arc; None for rapid/dwell
    center: tuple | None           # arc centre (x, y, z) absolute, m; arcs only
    clockwise: bool | None         # True for G2, False for G3, None otherwise
    dwell_s: float = 0.0           # G4 P, s
    blend_tolerance: float | None = None   # G64 P (m) / G61 (0) in force; None: the node's blend_tolerance_m


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


def _tokenize(code: str, n: int) -> list[_Word]:
    words = []
    i, size = 0, len(code)
    while i < size:
        c = code[i]
        if c.isspace():
            i += 1
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
        j = i
        while j < size and code[j] in _NUMBER_CHARS:
            j += 1
        text = code[i:j]
        if letter == 'O':          # before the rest of the line (o100 sub, o101 if [...]) is read as words
            raise GcodeError(n, f'O{text}: O-words (subroutines, loops, conditionals) are not supported')
        if not text:
            raise GcodeError(n, f'{letter}: malformed word: a number must follow the letter')
        if not _NUMBER.match(text):
            raise GcodeError(n, f'{letter}{text}: malformed number {text!r}')
        value = float(text)
        if not math.isfinite(value):           # 400 digits: a float's range ends near 1.8e308
            raise GcodeError(n, f'{letter}{text[:20]}{"..." if len(text) > 20 else ""}: number out of range '
                                f'({len(text)} characters)')
        words.append(_Word(letter, value, letter + text))
        i = j
    return words


def _check_point(start, name: str) -> tuple:
    try:
        values = tuple(float(v) for v in start)
    except (TypeError, ValueError):
        raise FieldError(name, f'expected 3 finite numbers (x, y, z) in m, got {start!r}') from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise FieldError(name, f'expected 3 finite numbers (x, y, z) in m, got {start!r}')
    return values


def parse_gcode(text: str, start=(0.0, 0.0, 0.0), start_angles=(0.0, 0.0, 0.0)) -> list[Move]:
    """Parse a G-code program into moves in SI units.

    ``start`` is the machine point (m) and ``start_angles`` the A, B, C angles (rad)
    before the first line; incremental words and arcs start from them. Raises ``GcodeError``
    (``line N: <word>: <reason>``) for anything outside the supported subset.
    """
    if not isinstance(text, str):
        raise TypeError(f'text: expected str, got {type(text).__name__}')
    pos = list(_check_point(start, 'start'))
    angles = [float(a) for a in start_angles]
    if len(angles) != 3 or not all(math.isfinite(a) for a in angles):
        raise FieldError('start_angles', f'expected 3 finite angles (A, B, C) in rad, got {start_angles!r}')

    unit = MM            # G21
    absolute = True      # G90
    motion = None        # modal 0/1/2/3
    feed = None          # m/s
    ended_at = None      # (line, word text) of M2/M30
    blend = None         # modal G61 (0.0) / G64 P (m) / G64 (None: the node's setting)
    moves: list[Move] = []

    for n, raw in enumerate(_LINE_SPLIT.split(text), start=1):
        code = _strip_comments(raw, n).strip()
        if not code or code == '%':
            continue
        words = _tokenize(code, n)
        if ended_at is not None:
            first = next((w for w in words if w.letter != 'N'), words[0])
            raise GcodeError(n, f'{first.text}: after program end ({ended_at[1]} on line {ended_at[0]})')

        # --- classify the words of the line --------------------------------------
        values: dict[str, _Word] = {}
        motion_word = dwell_word = plane_word = units_word = distance_word = end_word = path_word = None
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
                v = w.value
                if v in _MOTION:
                    if motion_word is not None:
                        raise GcodeError(n, f'{motion_word.text} and {w.text}: two motion codes on one line')
                    motion_word = w
                elif v == 4.0:
                    if dwell_word is not None:
                        raise GcodeError(n, f'{w.text}: G4 given twice on one line')
                    dwell_word = w
                elif v == 17.0:
                    if plane_word is not None:
                        raise GcodeError(n, f'{w.text}: G17 given twice on one line')
                    plane_word = w
                elif v in (18.0, 19.0):
                    raise GcodeError(n, f'{w.text}: unsupported plane: only the XY plane (G17) is supported')
                elif v in (20.0, 21.0):
                    if units_word is not None:
                        raise GcodeError(n, f'{units_word.text} and {w.text}: two unit codes on one line')
                    units_word = w
                elif v in (90.0, 91.0):
                    if distance_word is not None:
                        raise GcodeError(n, f'{distance_word.text} and {w.text}: two distance modes on one line')
                    distance_word = w
                elif v in (61.0, 64.0):
                    if path_word is not None:
                        raise GcodeError(n, f'{path_word.text} and {w.text}: two path control modes on one line')
                    path_word = w
                elif v == 40.0:
                    pass                   # cutter compensation off: the only state the planner has
                elif v in (41.0, 42.0, 41.1, 42.1):
                    raise GcodeError(n, f'{w.text}: cutter compensation is not supported (the planner follows '
                                        'the programmed path; G40 is accepted)')
                else:
                    raise GcodeError(n, f'{w.text}: unsupported G-code (supported: {_SUPPORTED_G})')
            elif L == 'M':
                if w.value not in (2.0, 30.0):
                    raise GcodeError(n, f'{w.text}: unsupported M-code (supported: M2 M30)')
                if end_word is not None:
                    raise GcodeError(n, f'{end_word.text} and {w.text}: two M-codes on one line')
                end_word = w
            elif L in _VALUE_LETTERS:
                if L in values:
                    raise GcodeError(n, f'{w.text}: {L} given twice on one line '
                                        f'(first {values[L].text})')
                values[L] = w
            elif L == 'K':
                raise GcodeError(n, f'{w.text}: unsupported word: K is not part of the I J arc form '
                                    '(arcs are in the XY plane only)')
            elif L == 'R':
                raise GcodeError(n, f'{w.text}: unsupported word: radius-form arcs (R) are not '
                                    'supported; give the centre with I J')
            else:
                raise GcodeError(n, f'{w.text}: unsupported word {L} (supported: '
                                    'G M N F X Y Z A B C I J P)')

        # --- modal settings first: they apply to every number of the line ---------
        if units_word is not None:
            unit = INCH if units_word.value == 20.0 else MM
        if distance_word is not None:
            absolute = distance_word.value == 90.0
        if 'F' in values:
            w = values['F']
            if not w.value > 0.0:
                raise GcodeError(n, f'{w.text}: feed rate must be > 0')
            feed = w.value * unit / 60.0

        axes = [values[a] for a in 'XYZABC' if a in values]
        offsets = [values[a] for a in 'IJ' if a in values]

        # --- path control (G61 / G64 P) -------------------------------------------
        if path_word is not None:
            if path_word.value == 61.0:
                if 'P' in values:
                    raise GcodeError(n, f"{values['P'].text}: P is not allowed with G61 (exact stop)")
                blend = 0.0
            elif dwell_word is not None:
                raise GcodeError(n, f'{dwell_word.text} and {path_word.text}: P would be both a dwell and a '
                                    'blending tolerance; put them on separate lines')
            elif 'P' in values:
                p = values['P']
                if p.value < 0.0:
                    raise GcodeError(n, f'{p.text}: G64 blending tolerance must be >= 0')
                blend = p.value * unit
            else:
                blend = None

        # --- dwell ---------------------------------------------------------------
        if dwell_word is not None:
            if motion_word is not None:
                raise GcodeError(n, f'{dwell_word.text} and {motion_word.text}: a dwell cannot share '
                                    'its line with a motion code')
            if axes or offsets:
                w = (axes + offsets)[0]
                raise GcodeError(n, f'{w.text}: axis word on a {dwell_word.text} (dwell) line; '
                                    'put the move on its own line')
            if 'P' not in values:
                raise GcodeError(n, f'{dwell_word.text}: dwell needs P<seconds>')
            p = values['P']
            if p.value < 0.0:
                raise GcodeError(n, f'{p.text}: dwell time must be >= 0 s')
            moves.append(Move('dwell', n, tuple(pos), (None, None, None), None, None, None, p.value))
        elif 'P' in values and (path_word is None or path_word.value != 64.0):
            raise GcodeError(n, f"{values['P'].text}: P is only allowed with G4 (dwell) or G64 (blending tolerance)")

        # --- motion --------------------------------------------------------------
        if motion_word is not None:
            motion = _MOTION[motion_word.value]
        if offsets and motion not in (2, 3):
            mode = 'no motion mode' if motion is None else f'G{motion}'
            raise GcodeError(n, f'{offsets[0].text}: I and J are only allowed with G2/G3 '
                                f'(active: {mode})')
        if axes or offsets:
            if motion is None:
                raise GcodeError(n, f'{(axes + offsets)[0].text}: no motion mode active '
                                    '(give G0, G1, G2 or G3 first)')
            mname = motion_word.text if motion_word is not None else f'G{motion} (modal)'
            if motion != 0 and feed is None:
                raise GcodeError(n, f'{mname}: no feed rate: F must be given before a G1/G2/G3 move')

            target = list(pos)
            for a, i in (('X', 0), ('Y', 1), ('Z', 2)):
                if a in values:
                    d = values[a].value * unit
                    target[i] = d if absolute else pos[i] + d
            new_angles = [None, None, None]
            for i, a in enumerate(_ANGLES):
                if a in values:
                    d = math.radians(values[a].value)
                    angles[i] = d if absolute else angles[i] + d
                    new_angles[i] = angles[i]

            if motion in (0, 1):
                moves.append(Move(_KIND[motion], n, tuple(target), tuple(new_angles),
                                  feed if motion == 1 else None, None, None, blend_tolerance=blend))
            else:
                if not offsets:
                    raise GcodeError(n, f'{mname}: arc without I and J: the centre is required '
                                        '(I J form)')
                named = ' '.join(w.text for w in offsets)
                if abs(target[2] - pos[2]) > HELIX_TOL_M:
                    raise GcodeError(n, f"{values['Z'].text}: Z change on an arc: helical arcs are "
                                        'not supported')
                target[2] = pos[2]
                ci = values['I'].value * unit if 'I' in values else 0.0
                cj = values['J'].value * unit if 'J' in values else 0.0
                center = (pos[0] + ci, pos[1] + cj, pos[2])
                r0 = math.hypot(ci, cj)
                if r0 < ZERO_RADIUS_M:
                    raise GcodeError(n, f'{mname} {named}: zero arc radius')
                r1 = math.hypot(target[0] - center[0], target[1] - center[1])
                tol = ARC_ABS_TOL_M + ARC_REL_TOL * r0
                if abs(r1 - r0) > tol:
                    raise GcodeError(n, f'{mname} {named}: end point not on the arc: radius '
                                        f'{r0:.9g} m at the start, {r1:.9g} m at the end '
                                        f'(differ by {abs(r1 - r0):.3g} m > {tol:.3g} m; '
                                        'I J inconsistent with the end point)')
                moves.append(Move('arc', n, tuple(target), tuple(new_angles), feed, center, motion == 2,
                                  blend_tolerance=blend))
            pos = target

        if end_word is not None:
            ended_at = (n, end_word.text)
    return moves
