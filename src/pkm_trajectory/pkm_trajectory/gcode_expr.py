"""LinuxCNC G-code real values: parameters, expressions and functions (pure Python).

Follows LinuxCNC's G-code overview (linuxcnc.org/docs/html/gcode/overview.html), sections
"Numbers", "Parameters", "Expressions", "Binary Operators", "Equality and floating-point
values" and "Functions"; where the text is silent, the LinuxCNC interpreter
(src/emc/rs274ngc/interp_read.cc, interp_execute.cc) decides.

``read_real`` reads one value (number, parameter, expression, function); ``read_assignment``
reads ``#<ref> = <value>`` for the caller to apply after the line. Errors are ``ExprError``.

Decisions where the text is silent, or where this module is stricter (documented, tested)
- Whitespace may separate tokens (around operators and brackets, after ``#`` or a function
  name, around ``=``), never split one: not inside a number, ``**`` or a name, nor between a
  sign and its value (``- 5``, as the word reader refuses ``X- 5``). ``#<P a R am>`` is ``#<param>``.
- A sign may precede any value (``-[..]``, ``-#1``, ``-SIN[..]``) and binds tighter than
  ``**``: ``[-2 ** 2]`` = 4 (LinuxCNC). Two signs are refused (LinuxCNC reads ``--1`` as 1).
- ``**`` is left-associative like every level ("Binary Operators"): ``[2 ** 3 ** 2]`` = 64.
- Numbered parameters are #1..#5399; ``#0`` is out of range, read or set (LinuxCNC refuses
  index < 1). A parameter number may be a real value within 0.0001 of an integer ("Numbers").
- ``MOD`` is LinuxCNC's ``fmod(a, b)``, plus ``|b|`` when negative: ``[-7 MOD 3]`` = 2; ``MOD``
  by zero is refused (LinuxCNC computes NaN, then refuses it).
- ``EXISTS`` takes only ``#<name>``. ``push_locals`` clears #1-#30 (unused arguments read 0).
"""

from __future__ import annotations

import math
import operator
import re

__all__ = ['ExprError', 'Parameters', 'read_real', 'read_assignment', 'MAX_PARAMETER']

MAX_PARAMETER = 5399        # numbered parameters #1..#5399 (this controller's range)
SUB_ARGS = 30               # #1-#30 hold a subroutine's arguments ("Subroutine Parameters")
TOLERANCE_EQUAL = 1e-6      # "Equality and floating-point values"
INTEGER_TOLERANCE = 1e-4    # "Numbers": an integer may be off by 0.0001
_QUOTE_MAX = 40             # longer texts are shortened in messages

_NUMBER = re.compile(r'[+-]?(?:\d+(?:\.\d*)?|\.\d+)\Z')
_NUMBER_CHARS = '0123456789.'
_WORD = re.compile(r'[A-Za-z]*')
_EXISTS = re.compile(r'\[\s*#\s*<([^>]*)>\s*\]')      # "Functions": EXISTS[#<name>] only


class ExprError(ValueError):
    """A real value cannot be read or evaluated; the message names the text (the caller prefixes 'line N: ')."""


def _short(text: str) -> str:
    text = text.strip()
    return text if len(text) <= _QUOTE_MAX else text[:_QUOTE_MAX - 3] + '...'


def _norm(name: str) -> str:
    """A parameter name as LinuxCNC keys it: lower case, spaces and tabs removed ("Named Parameters")."""
    return ''.join(name.split()).lower()


class Parameters:
    """Numbered (#1..#5399) and named (#<name> local, #<_name> global) parameters."""

    def __init__(self, numbered: dict[int, float] | None = None):
        self._numbered: dict[int, float] = {}      # unset numbered parameters read 0.0
        self._globals: dict[str, float] = {}
        self._locals: list[dict[str, float]] = [{}]  # one scope per call level, [0]: main program
        self._saved: list[dict[int, float]] = []    # callers' #1-#30, one per push_locals
        for key, value in (numbered or {}).items():
            self.set(key, value)

    @staticmethod
    def _index(key) -> int:
        if isinstance(key, bool) or not isinstance(key, int):
            raise TypeError(f'parameter key: expected int or str, got {key!r}')
        if not 1 <= key <= MAX_PARAMETER:
            raise ExprError(f'#{key}: parameter number out of range (1..{MAX_PARAMETER})')
        return key

    def _scope(self, name: str) -> dict[str, float]:
        # "Named Parameters": #<_name> is global, #<name> local to the current subroutine
        return self._globals if name.startswith('_') else self._locals[-1]

    def get(self, key) -> float:
        if isinstance(key, str):
            name = _norm(key)
            try:
                return self._scope(name)[name]
            except KeyError:   # "Parameters": uninitialized named parameters are an error
                raise ExprError(f'#<{name}> is not defined') from None
        return self._numbered.get(self._index(key), 0.0)

    def set(self, key, value: float) -> None:
        value = float(value)
        if not math.isfinite(value):
            raise ExprError(f'parameter value {value} is not finite')
        if isinstance(key, str):
            name = _norm(key)
            if not name:
                raise ExprError('#<>: empty parameter name')
            self._scope(name)[name] = value
        else:
            self._numbered[self._index(key)] = value

    def exists(self, name: str) -> bool:
        name = _norm(name)
        return name in self._scope(name)

    def push_locals(self) -> None:
        """Enter a subroutine: a new local scope; #1-#30 saved and cleared (its arguments go there)."""
        self._saved.append({k: self._numbered.pop(k) for k in range(1, SUB_ARGS + 1) if k in self._numbered})
        self._locals.append({})

    def pop_locals(self) -> None:
        """Leave a subroutine: its locals vanish; the caller's #1-#30 come back."""
        if not self._saved:
            raise RuntimeError('pop_locals without a matching push_locals')
        self._locals.pop()
        for k in range(1, SUB_ARGS + 1):
            self._numbered.pop(k, None)
        self._numbered.update(self._saved.pop())


def _mod(a: float, b: float) -> float:
    r = math.fmod(a, b)          # LinuxCNC MODULO "always calculates a positive answer"
    return r + abs(b) if r < 0.0 else r


# "Binary Operators": comparisons and logic give 1.0 / 0.0 (float() in _Reader.binary), nonzero is true;
# "Equality and floating-point values": EQ NE GE LE take values closer than 1e-6 as equal
_BINARY = {
    '**': math.pow, '*': operator.mul, '/': operator.truediv, 'MOD': _mod, '+': operator.add, '-': operator.sub,
    'EQ': lambda a, b: abs(a - b) < TOLERANCE_EQUAL, 'NE': lambda a, b: abs(a - b) >= TOLERANCE_EQUAL,
    'GT': operator.gt, 'GE': lambda a, b: a >= b or abs(a - b) < TOLERANCE_EQUAL,
    'LT': operator.lt, 'LE': lambda a, b: a <= b or abs(a - b) < TOLERANCE_EQUAL,
    'AND': lambda a, b: a != 0.0 and b != 0.0, 'OR': lambda a, b: a != 0.0 or b != 0.0,
    'XOR': lambda a, b: (a != 0.0) != (b != 0.0),
}
_OPERATORS = tuple(_BINARY)     # '**' before '*'
_GROUPS = (   # "Binary Operators" precedence, lowest first
    ('AND', 'OR', 'XOR'), ('EQ', 'NE', 'GT', 'GE', 'LT', 'LE'), ('+', '-'), ('*', '/', 'MOD'), ('**',))

# "Functions": angles in degrees; ROUND half away from zero as LinuxCNC's (int)(x +- 0.5)
_UNARY = {
    'ABS': abs, 'EXP': math.exp, 'LN': math.log, 'SQRT': math.sqrt,
    'ACOS': lambda x: math.degrees(math.acos(x)), 'ASIN': lambda x: math.degrees(math.asin(x)),
    'COS': lambda x: math.cos(math.radians(x)), 'SIN': lambda x: math.sin(math.radians(x)),
    'TAN': lambda x: math.tan(math.radians(x)),
    'FIX': lambda x: float(math.floor(x)), 'FUP': lambda x: float(math.ceil(x)),   # FIX[-2.8] = -3, FUP[-2.8] = -2
    'ROUND': lambda x: float(math.trunc(x + (-0.5 if x < 0.0 else 0.5))),
}
_DOMAIN = {'ACOS': 'argument outside [-1, 1]', 'ASIN': 'argument outside [-1, 1]',   # refused by LinuxCNC
           'SQRT': 'square root of a negative number', 'LN': 'logarithm of a number <= 0'}
_FUNCTIONS = ('ATAN', 'EXISTS', *_UNARY)     # no name is a prefix of another


class _Reader:
    """Recursive descent over one line: ``i`` is the position, ``open`` the unclosed '[' positions."""

    def __init__(self, code: str, params: Parameters, i: int):
        self.code, self.params, self.i, self.start, self.open = code, params, i, i, []

    def peek(self, k: int = 0) -> str:
        return self.code[self.i + k] if self.i + k < len(self.code) else ''

    def skip_space(self) -> None:
        while self.peek().isspace():
            self.i += 1

    def need(self, c: str, at: int, what: str) -> None:
        """After optional whitespace ``c`` must follow (not consumed); else quote from ``at``: what."""
        self.skip_space()
        if self.peek() != c:
            raise ExprError(f'{_short(self.code[at:self.i + 1])}: {what}')

    def context(self) -> str:
        """The innermost expression being read (to its ']'), else the text read so far."""
        if not self.open:
            return self.code[self.start:self.i + 1]
        depth, start = 0, self.open[-1]
        for j in range(start, len(self.code)):
            depth += {'[': 1, ']': -1}.get(self.code[j], 0)
            if depth == 0:
                return self.code[start:j + 1]
        return self.code[start:]

    def at_end(self, what: str = ''):
        what = "unclosed '[' (']' missing)" if self.open else what
        raise ExprError(f'{_short(self.code[self.start:]) or "(nothing)"}: {what}')

    def fail(self, at: int, reason: str):
        """The operation from ``at`` to here failed: quote its expression, or the operation if long."""
        text = self.context() if len(self.context().strip()) <= _QUOTE_MAX else self.code[at:self.i]
        raise ExprError(f'{_short(text)}: {reason}')

    def real(self) -> float:
        """Real value: [sign] (number | parameter | expression | function)."""
        self.skip_space()
        c, nxt = self.peek(), self.peek(1)
        if c and c in '+-' and not (nxt and nxt in _NUMBER_CHARS):
            if nxt and nxt in '+-':
                raise ExprError(f'{_short(self.code[self.i:self.i + 3])}: two signs in a row')
            if not nxt or nxt.isspace():
                raise ExprError(f"{_short(self.code[self.i:self.i + 3])}: sign '{c}' must be followed directly "
                                'by its value')
            self.i += 1
            value = self.real()
            return -value if c == '-' else value
        if c == '[':
            return self.expression()
        if c == '#':
            return self.params.get(self.reference())
        if c and c in _NUMBER_CHARS + '+-':
            return self.number()
        if c.isalpha():
            return self.function()
        if not c:
            self.at_end('missing value at end of line')
        raise ExprError(f'{_short(self.context())}: missing value before {c!r}')

    def number(self) -> float:
        """"Numbers": [+|-] digits [. digits] with at least one digit; no exponent."""
        j = self.i + 1
        while j < len(self.code) and self.code[j] in _NUMBER_CHARS:
            j += 1
        text = self.code[self.i:j]
        if not _NUMBER.match(text):
            raise ExprError(f'{_short(text)}: malformed number')
        value = float(text)
        if not math.isfinite(value):
            raise ExprError(f'{_short(text)}: number out of range ({len(text)} characters)')
        self.i = j
        return value

    def reference(self):
        """'#' then <name> or a parameter number (any real value: ##2, #[1+2]); returns the key."""
        at = self.i
        self.i += 1
        self.skip_space()
        if self.peek() == '<':
            return self.name(at)
        number = self.real()
        index, text = round(number), _short(self.code[at:self.i])
        if abs(number - index) > INTEGER_TOLERANCE:
            raise ExprError(f'{text}: parameter number must be an integer, got {number:g}')
        if not 1 <= index <= MAX_PARAMETER:
            raise ExprError(f'{text}: parameter number {index} out of range (1..{MAX_PARAMETER})')
        return index

    def name(self, at: int) -> str:
        """'<name>' after '#' ("Named Parameters")."""
        close = self.code.find('>', self.i)
        if close < 0:
            raise ExprError(f"{_short(self.code[at:])}: '>' missing after the parameter name")
        name = _norm(self.code[self.i + 1:close])
        if not name:
            raise ExprError(f'{self.code[at:close + 1]}: empty parameter name')
        self.i = close + 1
        return name

    def expression(self) -> float:
        """"Expressions": '[' group ']'."""
        self.open.append(self.i)
        self.i += 1
        value = self.group()
        c, word = self.peek(), _WORD.match(self.code, self.i).group()
        if not c:
            self.at_end()
        if c != ']':
            what = f'unknown operator {word!r}' if word else f"expected an operator or ']' before {c!r}"
            raise ExprError(f'{_short(self.context())}: {what}')
        self.i += 1
        self.open.pop()
        return value

    def group(self, level: int = 0) -> float:
        """Operands joined by the operators of precedence group ``level``, left to right; an operand
        is a group of the next level, below '**' a real value ("Binary Operators")."""
        operand = self.real if level == len(_GROUPS) - 1 else lambda: self.group(level + 1)
        self.skip_space()
        at, value = self.i, operand()
        while True:
            self.skip_space()
            op = next((o for o in _OPERATORS if self.code[self.i:self.i + len(o)].upper() == o), None)
            if op not in _GROUPS[level]:
                return value
            self.i += len(op)
            value = self.binary(op, value, operand(), at)

    def binary(self, op: str, a: float, b: float, at: int) -> float:
        if op in ('/', 'MOD') and b == 0.0:
            self.fail(at, 'division by zero' if op == '/' else 'MOD by zero')
        if op == '**' and a < 0.0 and b != math.floor(b):
            self.fail(at, f'negative base {a:g} with non-integer exponent {b:g}')
        try:
            value = float(_BINARY[op](a, b))
        except (OverflowError, ValueError, ZeroDivisionError):   # 10 ** 400, 0 ** -1
            value = math.nan
        if not math.isfinite(value):
            self.fail(at, 'result is not finite (overflow)')
        return value

    def function(self) -> float:
        """"Functions": NAME[arg], ATAN[y]/[x], EXISTS[#<name>]."""
        at = self.i
        name = next((f for f in _FUNCTIONS if self.code[at:at + len(f)].upper() == f), None)
        if name is None:
            word = _WORD.match(self.code, at).group()
            raise ExprError(f'{word}: unknown function (known: {" ".join(sorted(_FUNCTIONS))})')
        self.i += len(name)
        self.need('[', at, f"'[' missing after {name}")
        if name == 'EXISTS':
            return self.exists(at)
        x = self.expression()
        if name == 'ATAN':     # ATAN[y]/[x]: four quadrants, -180..180 degrees
            self.need('/', at, 'ATAN needs two arguments: ATAN[y]/[x]')
            self.i += 1
            self.need('[', at, "'[' missing after ATAN[y]/")
            return math.degrees(math.atan2(x, self.expression()))
        call = _short(self.code[at:self.i])
        try:
            return _UNARY[name](x)        # finite for a finite argument, or one of:
        except ValueError:                # math domain error: ACOS[2], SQRT[-1], LN[0]
            raise ExprError(f'{call}: {_DOMAIN[name]} ({x:g})') from None
        except OverflowError:             # EXP[1000]
            raise ExprError(f'{call}: result is not finite (overflow)') from None

    def exists(self, at: int) -> float:
        match = _EXISTS.match(self.code, self.i)
        if match is None:
            raise ExprError(f'{_short(self.code[at:])}: EXISTS takes one named parameter: EXISTS[#<name>]')
        self.i = match.end()
        return float(self.params.exists(_norm(match.group(1))))


def _guarded(read, code: str):
    try:
        return read()
    except RecursionError:
        raise ExprError(f'{_short(code)}: expression nested too deeply') from None


def read_real(code: str, i: int, params: Parameters) -> tuple[float, int]:
    """Read one real value starting at code[i] (after a word's letter): a number, a parameter (#12, ##2 indirection,
    #<name>), an expression [ ... ], a unary function (ABS[...], ATAN[...]/[...], ...), optionally preceded by a
    sign (+/-). Returns (value, index just after it). Whitespace before the value and between its tokens is
    skipped, never inside a number or a name (see the module notes)."""
    reader = _Reader(code, params, i)
    value = _guarded(reader.real, code)
    end = reader.i
    reader.skip_space()
    if reader.peek() == ']':
        raise ExprError(f"{_short(code[i:reader.i + 1])}: unbalanced ']' (no matching '[')")
    return value, end


def read_assignment(code: str, i: int, params: Parameters) -> tuple[tuple, int]:
    """At code[i] == '#': read '#<ref> = <real value>' and return ((key, value), index after). The caller applies all
    assignments of a line after the line is read (LinuxCNC: parameter setting happens after all reads on the line).
    key: int for a numbered parameter, the normalised name (str) for a named one."""
    reader = _Reader(code, params, i)
    if reader.peek() != '#':
        raise ExprError(f'{_short(code[i:])}: a parameter setting starts with #')
    key = _guarded(reader.reference, code)
    reader.need('=', i, "'=' missing in parameter setting (#<ref> = <value>)")
    value, end = read_real(code, reader.i + 1, params)
    return (key, value), end
