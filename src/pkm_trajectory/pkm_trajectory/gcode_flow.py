"""O-words (LinuxCNC's "O Codes"): subroutines, loops and conditionals, pure Python.

``Flow(codes, ...)`` reads the program's O-word lines before anything runs and matches
every block (sub/endsub, while/endwhile, do/while, if/elseif/else/endif,
repeat/endrepeat); a block without its end, an end without its block, a label used
for two blocks, a sub inside a sub are refused with their line. While the program
runs, ``Flow.step(index)`` executes the O-word of a line and returns the index of the
next line to run: the interpreter's program counter. Conditions and arguments are
``gcode_expr`` real values (``[#1 GT 0]``).

LinuxCNC's rules kept: a call's arguments become #1..#30 of the subroutine (the rest
0; the caller's restored on return, ``Parameters.push_locals``); a sub is called only
after its definition; a return value goes to ``#<_value>`` (``#<_value_returned>`` 1);
calls nest at most 10 deep. Labels are numbers or ``<names>``; ``o[expr]`` labels and
other words on an O line are refused. A program that runs more than ``MAX_LINES``
lines (an endless loop) is refused.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from .gcode_expr import ExprError, Parameters, read_real

__all__ = ['Flow', 'MAX_LINES', 'MAX_DEPTH', 'o_line']

MAX_LINES = 1_000_000        # lines run (loops included) before a program is refused as endless
MAX_DEPTH = 10               # "The maximum subroutine nesting level is 10"
_O_LINE = re.compile(r'(?i)\s*(?:n\d+\s*)?o\s*(\d+|<[^>]*>)\s*([a-z]+)\s*(.*)\Z')
_KEYWORDS = ('sub', 'endsub', 'call', 'return', 'while', 'endwhile', 'do', 'if', 'elseif', 'else', 'endif',
             'repeat', 'endrepeat', 'break', 'continue')
_OPENS = {'sub': 'endsub', 'while': 'endwhile', 'do': 'while', 'if': 'endif', 'repeat': 'endrepeat'}


@dataclass
class OLine:
    label: str           # 'o100' or 'o<name>', lower case without spaces
    keyword: str
    rest: str            # what follows the keyword: [expr] arguments or a condition
    text: str            # as written, for errors
    block: int = -1      # the index of the line that opens its block
    end: int = -1        # of an opening line: the index of its block's end
    branches: list = field(default_factory=list)    # of an if: its elseif/else lines, in order


def o_line(code: str) -> OLine | None:
    """The O-word of a line (comments stripped), None for any other line."""
    m = _O_LINE.match(code)
    if m is None:
        return None
    label = 'o' + m.group(1).lower().replace(' ', '')
    return OLine(label, m.group(2).lower(), m.group(3).strip(), f'O{m.group(1)} {m.group(2).lower()}')


class Flow:
    """The O-word blocks of a program (``codes``: each line's code, comments stripped)
    and the state of their execution. ``error(index, message)`` raises the caller's
    GcodeError for that line."""

    def __init__(self, codes: list[str], params: Parameters, error):
        self.params, self.error = params, error
        self.lines: dict[int, OLine] = {}
        self.subs: dict[str, int] = {}
        self.calls: list[tuple] = []         # (the call's index, the caller's repeat counters)
        self.counts: dict[int, int] = {}     # repeat loops: iterations left, by their opening index
        stack: list[int] = []
        for i, code in enumerate(codes):
            o = o_line(code) if code[:1].lower() in 'on' else None
            if o is None:
                if code.lstrip()[:1].lower() == 'o':
                    self.error(i, f'{code.strip()[:20]}: malformed O-word (o<number or <name>> <keyword> ...)')
                continue
            if o.keyword not in _KEYWORDS:
                self.error(i, f'{o.text}: unknown O-word keyword (supported: {" ".join(_KEYWORDS)})')
            self.lines[i] = o
            self._match(i, o, stack)
        if stack:
            o = self.lines[stack[-1]]
            self.error(stack[-1], f'{o.text}: no {_OPENS[o.keyword]} for this {o.keyword}')

    def _match(self, i: int, o: OLine, stack: list) -> None:
        """Pair each block's lines (a pre-scan: the program runs only when they match)."""
        top = self.lines[stack[-1]] if stack else None
        if o.keyword == 'while' and top is not None and top.keyword == 'do' and top.label == o.label:
            o.block, top.end = stack.pop(), i          # the while that closes a do
            return
        if o.keyword in _OPENS:
            if o.keyword == 'sub':
                if any(self.lines[k].keyword == 'sub' for k in stack):
                    self.error(i, f'{o.text}: subroutines may not be nested')
                if o.label in self.subs:
                    self.error(i, f'{o.text}: subroutine {o.label} defined twice')
                self.subs[o.label] = i
            if any(self.lines[k].label == o.label for k in stack):
                self.error(i, f'{o.text}: label {o.label} already used by an open block')
            stack.append(i)
            return
        if o.keyword in ('call',):
            return
        openers = {'endsub': 'sub', 'return': 'sub', 'endwhile': 'while', 'elseif': 'if', 'else': 'if',
                   'endif': 'if', 'endrepeat': 'repeat', 'break': None, 'continue': None}[o.keyword]
        for k in reversed(stack):
            opener = self.lines[k]
            if opener.label == o.label and (openers is None or opener.keyword == openers):
                if openers is None and opener.keyword not in ('while', 'do', 'repeat'):
                    break
                o.block = k
                if o.keyword in ('elseif', 'else'):
                    opener.branches.append(i)
                elif o.keyword not in ('return', 'break', 'continue'):
                    if stack[-1] != k:
                        inner = self.lines[stack[-1]]
                        self.error(i, f'{o.text}: {inner.text} (line {stack[-1] + 1}) is not closed before it')
                    opener.end = i
                    stack.pop()
                return
        self.error(i, f'{o.text}: no open {openers or "loop"} {o.label} for this {o.keyword}')

    def value(self, i: int, text: str) -> float:
        try:
            value, end = read_real(text, 0, self.params)
        except ExprError as exc:
            self.error(i, f'{self.lines[i].text}: {exc}')
        if text[end:].strip():
            self.error(i, f'{self.lines[i].text}: unexpected {text[end:].strip()[:20]!r} after its [ ] value')
        return value

    def arguments(self, i: int, text: str) -> list:
        out, k = [], 0
        while text[k:].strip():
            try:
                v, k = read_real(text, k, self.params)
            except ExprError as exc:
                self.error(i, f'{self.lines[i].text}: {exc}')
            out.append(v)
        return out

    def step(self, i: int) -> int:
        """Run the O-word of line ``i``; the index of the next line to run."""
        o = self.lines[i]
        kw = o.keyword
        if kw == 'sub':
            return o.end + 1                       # a definition: skipped until called
        if kw in ('do', 'endif'):
            return i + 1
        if kw == 'call':
            start = self.subs.get(o.label)
            if start is None or start > i:
                self.error(i, f'{o.text}: subroutine {o.label} is not defined before this call')
            if len(self.calls) >= MAX_DEPTH:
                self.error(i, f'{o.text}: calls nested deeper than {MAX_DEPTH}')
            args = self.arguments(i, o.rest)
            if len(args) > 30:
                self.error(i, f'{o.text}: at most 30 arguments, got {len(args)}')
            self.params.push_locals()
            for n, v in enumerate(args, start=1):
                self.params.set(n, v)
            self.calls.append((i, self.counts))
            self.counts = {}                        # each call its own repeat counters (a recursive call)
            return start + 1
        if kw in ('endsub', 'return'):
            if not self.calls:
                self.error(i, f'{o.text}: not in a called subroutine')
            if o.rest:
                value = self.value(i, o.rest)
                self.params.set('_value', value)
                self.params.set('_value_returned', 1.0)
            self.params.pop_locals()
            caller, self.counts = self.calls.pop()
            return caller + 1
        if kw in ('while', 'if', 'elseif'):
            if kw == 'while' and o.block >= 0:         # the end of a do: again while true
                return o.block + 1 if self.value(i, o.rest) else i + 1
            if kw == 'elseif':                         # reached from the branch before: done
                return self.lines[o.block].end + 1
            if self.value(i, o.rest):
                return i + 1
            if kw == 'while':
                return o.end + 1
            for b in o.branches:                       # the if's next branch that holds
                branch = self.lines[b]
                if branch.keyword == 'else' or self.value(b, branch.rest):
                    return b + 1
            return o.end + 1
        if kw == 'else':
            return self.lines[o.block].end + 1
        if kw == 'endwhile':
            return o.block
        if kw == 'repeat':
            count = self.value(i, o.rest)
            if count < 1:
                return o.end + 1
            self.counts[i] = int(count)
            return i + 1
        if kw == 'endrepeat':
            self.counts[o.block] -= 1
            return o.block + 1 if self.counts[o.block] > 0 else i + 1
        loop = self.lines[o.block]
        if kw == 'break':
            return loop.end + 1
        # continue: to the loop's test (a while's line, a do's closing while, a repeat's end)
        return o.block if loop.keyword == 'while' else loop.end
