"""O-words as LinuxCNC's "O Codes" reference has them, its examples worked by hand:
subroutines with arguments (#1.. restored on return, a return value), while, do-while,
if/elseif/else, repeat, break and continue; blocks without their end, calls before the
definition, nesting deeper than 10 and endless loops refused with their line."""

import pytest

from pkm_trajectory import gcode
from pkm_trajectory.gcode import GcodeError, parse_gcode
from pkm_trajectory.gcode_expr import Parameters


def xs(text, **kwargs):
    return [round(m.target[0] * 1e3, 6) for m in parse_gcode('G21 G90 G1 F600\n' + text, **kwargs)]


def test_subroutine_arguments_are_its_parameters_and_the_callers_come_back():
    text = ('#1 = 7\no100 sub\nG1 X#1 Y#2\no100 endsub\no100 call [10] [20]\no100 call [30]\nG1 X#1\n')
    moves = parse_gcode('G21 G90 G1 F600\n' + text)
    assert [(round(m.target[0] * 1e3), round(m.target[1] * 1e3)) for m in moves] == [(10, 20), (30, 0), (7, 0)]


def test_return_value():
    params = Parameters()
    parse_gcode('o200 sub\no200 return [#1 * 2]\no200 endsub\no200 call [21]\n', parameters=params)
    assert params.get('_value') == 42.0 and params.get('_value_returned') == 1.0


def test_while_do_while_repeat():
    assert xs('#1 = 0\no101 while [#1 LT 3]\nG1 X#1\n#1 = [#1 + 1]\no101 endwhile\n') == [0, 1, 2]
    # do-while runs its body once before the test
    assert xs('#1 = 0\no100 do\nG1 X#1\n#1 = [#1 + 2]\no100 while [#1 LT 6]\n') == [0, 2, 4]
    assert xs('#1 = 9\no100 do\nG1 X#1\no100 while [#1 LT 6]\n') == [9]
    assert xs('G91\no103 repeat [3]\nG1 X1\no103 endrepeat\n') == [1, 2, 3]
    assert xs('o103 repeat [0]\nG1 X1\no103 endrepeat\nG1 X5\n') == [5]


def test_if_elseif_else():
    program = ('o102 if [#1 GT 5]\nG1 X1\no102 elseif [#1 GT 2]\nG1 X2\no102 else\nG1 X3\no102 endif\nG1 X9\n')
    for value, expected in ((7, [1, 9]), (3, [2, 9]), (1, [3, 9])):
        assert xs(f'#1 = {value}\n' + program) == expected, value


def test_break_and_continue():
    text = ('#1 = 0\no101 while [#1 LT 10]\n#1 = [#1 + 1]\no102 if [#1 EQ 2]\no101 continue\no102 endif\n'
            'o103 if [#1 EQ 4]\no101 break\no103 endif\nG1 X#1\no101 endwhile\nG1 X0\n')
    assert xs(text) == [1, 3, 0]


def test_nested_calls_and_loops():
    text = ('o10 sub\no11 repeat [#1]\nG91 G1 X1\no11 endrepeat\nG90\no10 endsub\n'
            'o20 sub\no10 call [#1]\no10 call [1]\no20 endsub\no20 call [2]\n')
    assert xs(text) == [1, 2, 3]


@pytest.mark.parametrize('text, line, fragments', [
    ('o100 sub\nG1 X1', 2, ['O100 sub', 'no endsub']),
    ('G1 X1\no101 endwhile', 3, ['O101 endwhile', 'no open while']),
    ('o101 while [1]\no102 if [1]\no101 endwhile\no102 endif', 4, ['O101 endwhile', 'O102 if', 'not closed']),
    ('o100 call\no100 sub\no100 endsub', 2, ['O100 call', 'not defined before']),
    ('o100 sub\no100 call\no100 endsub\no100 call', 3, ['O100 call', 'deeper than 10']),
    ('o100 sub\no101 sub\no101 endsub\no100 endsub', 3, ['O101 sub', 'not be nested']),
    ('o100 foo', 2, ['O100 foo', 'unknown O-word keyword']),
    ('o101 while [1/0]\no101 endwhile', 2, ['division by zero']),
    ('o101 break', 2, ['O101 break', 'no open loop']),
    ('G1 X1 o100 call', 2, ['O100', 'must begin its line']),
])
def test_flow_errors_name_line_and_word(text, line, fragments):
    with pytest.raises(GcodeError) as info:
        parse_gcode('G21\n' + text)
    assert info.value.line == line and all(f in str(info.value) for f in fragments), str(info.value)


def test_an_endless_loop_is_refused(monkeypatch):
    monkeypatch.setattr(gcode, 'MAX_LINES', 5000)
    with pytest.raises(GcodeError, match='run 5000 lines: an endless loop'):
        parse_gcode('G21\no1 while [1]\no1 endwhile\n')


def test_a_loop_that_makes_too_many_moves_is_refused_as_it_gets_there():
    """Memory stays flat: a million-iteration loop (or L repeats of a cycle) is refused at
    the move over the limit, not after its moves have filled the memory."""
    with pytest.raises(GcodeError, match=r'line 3: the program makes more than 1000 moves'):
        parse_gcode('G21 G1 F600\no1 repeat [1000000]\nG1 X1\nG1 X0\no1 endrepeat\n', max_moves=1000)
    with pytest.raises(GcodeError, match=r'line 2: the program makes more than 1000 moves'):
        parse_gcode('G21 G0 Z5\nG81 X1 R1 Z-1 L1000000000 F100\n', max_moves=1000)


def test_a_recursive_call_keeps_its_callers_repeat_count():
    text = ('o1 sub\no2 repeat [3]\nG1 X1\no3 if [#1 GT 0]\no1 call [#1 - 1]\no3 endif\no2 endrepeat\no1 endsub\n'
            'o1 call [1]\n')
    assert len(xs(text)) == 3 + 3 * 3         # the outer three, each with an inner three
