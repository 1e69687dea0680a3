"""LinuxCNC tool table (``tool.tbl``) reader: one tool per line, in SI units.

Pure Python (no rclpy, no numpy). The format is LinuxCNC's (docs: "Tool Table
Format", since 2.4): words ``T P X Y Z A B C U V W D I J Q`` in any order, separated by
spaces or tabs, letters in either case, ``;`` starts the comment (the rest of the line),
blank lines and lines starting with ``;`` are ignored. Values are in the table's unit
(LinuxCNC: machine units); ``unit`` gives metres per table unit (1e-3 for mm tables,
0.0254 for inch tables). Linear offsets (X Y Z U V W) and D are converted to metres,
rotary offsets (A B C, degrees in the table) to radians as in ``pkm_trajectory.gcode``;
the lathe angles ``I``/``J`` stay in degrees and ``Q`` (orientation) is an integer 0..9.

Stricter than LinuxCNC, which skips an unreadable line with a warning on stderr: every
line is understood or refused with ``ToolTableError`` ("tool table line N: <word>:
<reason>"). Refused: a line without ``T``, ``T0`` (LinuxCNC's "no tool" on non-random
changers), a tool or pocket number that is not an unsigned integer, a duplicate tool
or pocket number, a repeated letter, a letter outside ``TPXYZABCUVWDIJQ``, a number
that is not a finite decimal, a negative diameter, ``Q`` outside 0..9. ``P`` is
optional here (``pocket`` None; LinuxCNC requires it, a PKM has no changer).
The old pre-2.4 column format (no letters) is refused as unknown words.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

__all__ = ['Tool', 'ToolTableError', 'parse_tool_table', 'load_tool_table']

AXES = 'XYZABCUVW'
ROTARY = frozenset('ABC')
_LINE_SPLIT = re.compile(r'\r\n|\n|\r')
_LETTERS = frozenset('TP' + AXES + 'DIJQ')
_INT = re.compile(r'\d+\Z')
_REAL = re.compile(r'[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z')


@dataclass(frozen=True)
class Tool:
    """One tool of the table. ``offsets``/``diameter`` in metres; ``raw`` keeps every
    number as read (table units, degrees), keyed by letter, T and P included."""

    number: int                    # T, >= 1
    pocket: int | None             # P, None if the line has none
    offsets: dict                  # axis letter -> offset, m (A B C: rad); only the axes given
    diameter: float | None         # D in m, None if the line has none
    comment: str                   # text after ';', stripped ('' if none)
    line: int = 0                  # 1-based line of the table
    front_angle_deg: float | None = None   # I (lathe)
    back_angle_deg: float | None = None    # J (lathe)
    orientation: int | None = None         # Q (lathe), 0..9
    raw: dict = field(default_factory=dict)

    @property
    def length_m(self) -> float:
        """The tool length offset (Z), m; 0.0 if the table gives none."""
        return self.offsets.get('Z', 0.0)


class ToolTableError(ValueError):
    """A tool table refused; ``str()``: "tool table line N: <word>: <reason>"."""

    def __init__(self, line: int, word: str, reason: str):
        self.line, self.word, self.reason = line, word, reason
        super().__init__(f'tool table line {line}: {word}: {reason}')

    def __reduce__(self):
        return type(self), (self.line, self.word, self.reason)


def _words(code: str, n: int) -> dict:
    """letter -> (text as written, value) for the words of one line's code."""
    words = {}
    for token in code.split():
        letter, text = token[0].upper(), token[1:]
        if letter not in _LETTERS:
            raise ToolTableError(n, token, f'unknown word (letters are {" ".join("TP" + AXES + "DIJQ")})')
        if letter in words:
            raise ToolTableError(n, token, f'{letter} repeated on the line (first {words[letter][0]})')
        if letter in 'TPQ':
            if not _INT.match(text):
                raise ToolTableError(n, token, f'{letter} must be an unsigned integer')
            value = int(text)
        else:
            if not _REAL.match(text):
                raise ToolTableError(n, token, 'not a number')
            value = float(text)
            if not math.isfinite(value):
                raise ToolTableError(n, token, 'not a finite number')
        words[letter] = (token, value)
    return words


def parse_tool_table(text: str, unit: float = 1e-3) -> dict[int, Tool]:
    """The tools of a LinuxCNC tool table, by tool number (in the table's order)."""
    if isinstance(unit, bool) or not isinstance(unit, (int, float)) or not math.isfinite(unit) or unit <= 0:
        raise ValueError(f'unit: must be a positive finite number of metres per table unit, got {unit!r}')
    tools: dict[int, Tool] = {}
    pockets: dict[int, int] = {}
    for n, raw_line in enumerate(_LINE_SPLIT.split(text), start=1):
        code, _, comment = raw_line.partition(';')
        if not code.strip():
            continue
        words = _words(code, n)
        if 'T' not in words:
            raise ToolTableError(n, 'T', f'missing: every tool line needs a tool number ({code.split()[0]} ...)')
        t_word, number = words['T']
        if number == 0:
            raise ToolTableError(n, t_word, "T0 means 'no tool' in LinuxCNC; tool numbers start at 1")
        if number in tools:
            raise ToolTableError(n, t_word, f'duplicate tool number (first on line {tools[number].line})')
        pocket = words['P'][1] if 'P' in words else None
        if pocket is not None:
            if pocket in pockets:
                raise ToolTableError(n, words['P'][0], f'duplicate pocket number (first on line {pockets[pocket]})')
            pockets[pocket] = n
        diameter = None
        if 'D' in words:
            if words['D'][1] < 0:
                raise ToolTableError(n, words['D'][0], 'negative diameter')
            diameter = words['D'][1] * unit
        if 'Q' in words and words['Q'][1] > 9:
            raise ToolTableError(n, words['Q'][0], 'orientation must be 0..9')
        tools[number] = Tool(
            number=number, pocket=pocket,
            offsets={a: math.radians(words[a][1]) if a in ROTARY else words[a][1] * unit
                     for a in AXES if a in words},
            diameter=diameter, comment=comment.strip(), line=n,
            front_angle_deg=words['I'][1] if 'I' in words else None,
            back_angle_deg=words['J'][1] if 'J' in words else None,
            orientation=words['Q'][1] if 'Q' in words else None,
            raw={letter: value for letter, (_, value) in words.items()})
    return tools


def load_tool_table(path, unit: float = 1e-3) -> dict[int, Tool]:
    """``parse_tool_table`` of the file at ``path`` (UTF-8 text)."""
    with open(path, encoding='utf-8') as f:
        return parse_tool_table(f.read(), unit)
