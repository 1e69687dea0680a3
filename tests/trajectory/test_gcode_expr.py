"""pkm_trajectory.gcode_expr: LinuxCNC real values (parameters, expressions, functions).

Expected values are worked by hand from LinuxCNC's G-code overview ("Numbers", "Parameters",
"Expressions", "Binary Operators", "Equality and floating-point values", "Functions") and,
where the text is silent, from the LinuxCNC interpreter's behaviour (noted per test).
"""

import math
import re

import pytest

from pkm_trajectory.gcode_expr import MAX_PARAMETER, ExprError, Parameters, read_assignment, read_real

approx = pytest.approx


def value(text, params=None, **numbered):
    """The value of ``text`` read whole (the returned index must be its end)."""
    params = params if params is not None else Parameters({int(k[1:]): v for k, v in numbered.items()})
    result, end = read_real(text, 0, params)
    assert end == len(text.rstrip()), (text, end)
    return result


def fails(text, message, params=None):
    """``text`` is refused with a message matching ``message`` (a regular expression)."""
    with pytest.raises(ExprError, match=message):
        read_real(text, 0, params if params is not None else Parameters())


# --- the reference's examples ---------------------------------------------------------------

def test_reference_expression_example():
    # "Expressions": [1 + acos[0] - [#3 ** [4.0/2]]] with #3 = 2: 1 + 90 - 2**2 = 87
    assert value('[1 + acos[0] - [#3 ** [4.0/2]]]', p3=2.0) == approx(87.0)


def test_reference_precedence_example():
    # "Binary Operators": [[[2.0 / 3] * 1.5] - [5.5 / 11.0]] = 1.0 - 0.5
    assert value('[2.0 / 3 * 1.5 - 5.5 / 11.0]') == approx(0.5)


@pytest.mark.parametrize('text, expected', [
    ('[2 + 3 * 4]', 14.0),
    ('[2 - 3 * 4 / 5]', -0.4),                    # interp_read.cc: [2 - [[3 * 4] / 5]]
    ('[9+8*7/6+5-4*3**2+1]', 9 + 56 / 6 + 5 - 36 + 1),
    ('[2 ** 3 ** 2]', 64.0),                       # same group: the left one first, (2**3)**2
    ('[2 * 3 ** 2]', 18.0),                        # ** above *
    ('[2 ** 3 * 2]', 16.0),
    ('[12 / 3 MOD 3]', 1.0),                       # / and MOD one group: [12/3] MOD 3
    ('[1 + 1 EQ 2]', 1.0),                         # + above EQ
    ('[2 GT 1 + 1]', 0.0),                         # 2 > 2 is false
    ('[1 LT 2 AND 3 GT 4]', 0.0),                  # comparisons above AND
    ('[1 OR 1 AND 0]', 0.0),                       # AND OR XOR one group: [1 OR 1] AND 0
    ('[0 AND 1 OR 1]', 1.0),
    ('[[1 + 2] * 3]', 9.0),
])
def test_precedence_and_left_to_right(text, expected):
    assert value(text) == approx(expected)


def test_sign_binds_tighter_than_power():
    # LinuxCNC reads -2 as a number and -[..], -#1 as a negated value: [-2 ** 2] = 4
    assert value('[-2 ** 2]') == 4.0
    assert value('[0 - 2 ** 2]') == -4.0
    assert value('[-#1 ** 2]', p1=3.0) == 9.0


# --- numbers and signs --------------------------------------------------------------------

@pytest.mark.parametrize('text, expected', [
    ('1', 1.0), ('-.5', -0.5), ('1.', 1.0), ('+3', 3.0), ('007.50', 7.5), ('.5', 0.5),
    ('-[1 + 1]', -2.0), ('+[2]', 2.0), ('-#1', -4.0), ('-ABS[-2]', -2.0),
    ('[1--1]', 2.0), ('[1 - -1]', 2.0), ('[3 * -2]', -6.0),
])
def test_numbers_and_signs(text, expected):
    assert value(text, p1=4.0) == expected


def test_number_errors():
    fails('1.2.3', r"^1\.2\.3: malformed number$")
    fails('.', r'^\.: malformed number$')
    fails('1' + '0' * 400, r'number out of range \(401 characters\)')
    fails('- 5', r"^- 5: sign '-' must be followed directly by its value$")
    fails('[1 * - 5]', r"^- 5: sign '-' must be followed directly")
    fails('--1', r'^--1: two signs in a row$')
    fails('+-1', r'two signs in a row')


def test_exponent_is_not_part_of_a_number():
    # "Numbers" has no exponent: 1E5 is 1, the E is left to the caller (the next word)
    assert read_real('1E5', 0, Parameters()) == (1.0, 1)


# --- read_real's index ------------------------------------------------------------------------

@pytest.mark.parametrize('code, i, expected', [
    ('G1 X[1 + 2] Y3', 4, (3.0, 11)),
    ('X  5 Y', 1, (5.0, 4)),           # whitespace after the letter is skipped, trailing is not
    ('X-.5Y1', 1, (-0.5, 4)),
    ('X#1 Y2', 1, (4.0, 3)),
    ('X ATAN[1]/[1] Y', 1, (45.0, 13)),
    ('XABS[-1]F2', 1, (1.0, 8)),
    ('X#<_a>Y', 1, (2.0, 6)),
    ('X1.5 ]', 1, None),               # a stray ']' after the value is refused
])
def test_read_real_returns_the_index_after_the_value(code, i, expected):
    params = Parameters({1: 4.0})
    params.set('_a', 2.0)
    if expected is None:
        with pytest.raises(ExprError, match=r"^1\.5 ]: unbalanced ']' \(no matching '\['\)$"):
            read_real(code, i, params)
    else:
        assert read_real(code, i, params) == expected


def test_whitespace_between_tokens_only():
    assert value('[ 1 + 2 ]') == 3.0
    assert value('[2**3]') == 8.0
    assert value('ABS [-1]') == 1.0
    assert value('ATAN [1] / [1]') == approx(45.0)
    assert value('# 3', p3=5.0) == 5.0
    fails('[2 * * 3]', r"missing value before '\*'")
    fails('[1 M OD 2]', r"unknown operator 'M'")
    fails('[1 2]', r"^\[1 2\]: expected an operator or '\]' before '2'$")


# --- operators ----------------------------------------------------------------------------

@pytest.mark.parametrize('text, expected', [
    ('[7 MOD 3]', 1.0), ('[-7 MOD 3]', 2.0), ('[7 MOD -3]', 1.0), ('[-7 MOD -3]', 2.0),
    ('[7.5 MOD 2]', 1.5),               # LinuxCNC: fmod, plus |b| when negative
    ('[1 AND 2]', 1.0), ('[1 AND 0]', 0.0), ('[-0.5 AND 3]', 1.0),
    ('[0 OR 0]', 0.0), ('[0 OR 2]', 1.0),
    ('[1 XOR 1]', 0.0), ('[1 XOR 0]', 1.0), ('[0 XOR 0]', 0.0),
    ('[2 EQ 2]', 1.0), ('[2 NE 2]', 0.0), ('[3 GT 2]', 1.0), ('[2 GE 2]', 1.0),
    ('[2 LT 2]', 0.0), ('[2 LE 2]', 1.0),
    ('[7 mod 3]', 1.0), ('[1 eq 1]', 1.0), ('[1 and 0]', 0.0),   # case-insensitive
    ('[2 ** -1]', 0.5), ('[-2 ** 3]', -8.0), ('[5 / 2]', 2.5),
])
def test_binary_operators(text, expected):
    assert value(text) == approx(expected)


@pytest.mark.parametrize('text, expected', [
    # "Equality and floating-point values": closer than 1e-6 is equal, for EQ NE GE LE
    ('[1 EQ 1.0000001]', 1.0), ('[1 NE 1.0000001]', 0.0),
    ('[1 EQ 1.00001]', 0.0), ('[1 NE 1.00001]', 1.0),
    ('[1.0000001 LE 1]', 1.0), ('[1 GE 1.0000001]', 1.0),
    ('[1.0000001 GT 1]', 1.0), ('[1 LT 1.0000001]', 1.0),   # GT LT are strict (LinuxCNC)
])
def test_equality_tolerance(text, expected):
    assert value(text) == expected


# --- functions ----------------------------------------------------------------------------

@pytest.mark.parametrize('text, expected', [
    ('ABS[-2.5]', 2.5),
    ('ACOS[0.5]', math.degrees(math.acos(0.5))),
    ('ASIN[-0.5]', math.degrees(math.asin(-0.5))),
    ('COS[60]', math.cos(math.radians(60))),
    ('EXP[1.5]', math.exp(1.5)),
    ('LN[10]', math.log(10)),
    ('SIN[30]', math.sin(math.radians(30))),
    ('SQRT[2]', math.sqrt(2)),
    ('TAN[45]', math.tan(math.radians(45))),
    ('acos[0]', 90.0), ('Sin[90]', 1.0),
    ('SQRT[[3 * 3] + 16]', 5.0),
])
def test_functions_match_the_math_module(text, expected):
    assert value(text) == approx(expected, rel=1e-15, abs=1e-15)


@pytest.mark.parametrize('y, x, expected', [
    (1, 1, 45.0), (1, -1, 135.0), (-1, -1, -135.0), (-1, 1, -45.0),
    (0, -1, 180.0), (1, 0, 90.0), (-1, 0, -90.0), (0, 0, 0.0), (0, 1, 0.0),
])
def test_atan_four_quadrants_in_degrees(y, x, expected):
    assert value(f'ATAN[{y}]/[{x}]') == approx(expected)


@pytest.mark.parametrize('text, expected', [
    # ROUND: LinuxCNC (int)(x +- 0.5), halves away from zero
    ('ROUND[2.5]', 3.0), ('ROUND[-2.5]', -3.0), ('ROUND[0.5]', 1.0), ('ROUND[-0.5]', -1.0),
    ('ROUND[2.4999]', 2.0), ('ROUND[-2.4]', -2.0), ('ROUND[-2.6]', -3.0),
    # "Functions": FIX[2.8] = 2, FIX[-2.8] = -3, FUP[2.8] = 3, FUP[-2.8] = -2
    ('FIX[2.8]', 2.0), ('FIX[-2.8]', -3.0), ('FIX[-2.5]', -3.0), ('FIX[-2]', -2.0),
    ('FUP[2.8]', 3.0), ('FUP[-2.8]', -2.0), ('FUP[-2.5]', -2.0), ('FUP[2]', 2.0),
])
def test_round_fix_fup(text, expected):
    result = value(text)
    assert result == expected and isinstance(result, float)


def test_atan_slash_is_not_a_division():
    assert value('[ATAN[1]/[1] * 2]') == approx(90.0)
    assert value('[ABS[1]/[2]]') == 0.5          # other functions take one argument


def test_exists():
    params = Parameters()
    assert value('EXISTS[#<_global>]', params) == 0.0
    params.set('_global', 4711)
    assert value('EXISTS[#<_global>]', params) == 1.0
    assert value('[EXISTS[ # <_Glo bal> ] + 1]', params) == 2.0
    fails('EXISTS[#5]', r'^EXISTS\[#5\]: EXISTS takes one named parameter: EXISTS\[#<name>\]$')
    fails('EXISTS[[1]]', r'EXISTS takes one named parameter')


# --- parameters -------------------------------------------------------------------------

def test_numbered_parameters_and_indirection():
    params = Parameters({1: 5.0, 2: 7.0, 3: 30.0, 7: 42.0})
    assert value('[#1+2]', params) == 7.0       # "#1+2" is #1 plus 2, not #3
    assert value('#[1+2]', params) == 30.0
    assert value('##2', params) == 42.0          # the parameter whose number is in #2
    assert value('#[#2]', params) == 42.0
    assert value('#[2.00001]', params) == 7.0    # within 0.0001 of an integer ("Numbers")
    assert value('#99', params) == 0.0           # unset numbered parameters read 0
    assert value(f'#{MAX_PARAMETER}', params) == 0.0


def test_numbered_parameter_errors():
    params = Parameters({2: 6000.0})
    fails('#[1.5]', r'^#\[1\.5\]: parameter number must be an integer, got 1\.5$')
    fails('#1.5', r'^#1\.5: parameter number must be an integer')
    fails('#0', r'^#0: parameter number 0 out of range \(1\.\.5399\)$')
    fails('#5400', r'^#5400: parameter number 5400 out of range')
    fails('#-1', r'parameter number -1 out of range')
    fails('##2', r'^##2: parameter number 6000 out of range', params)
    fails('#', r'missing value at end of line')


def test_named_parameters():
    params = Parameters()
    params.set('param', 1.5)
    assert value('#<param>', params) == 1.5
    assert value('#<P a R am >', params) == 1.5   # lower-cased, spaces removed ("Named Parameters")
    assert value('[#<PARAM> * 2]', params) == 3.0
    params.set('_Endmill Dia', 0.049)
    assert params.get('_endmilldia') == 0.049 and params.exists('_ENDMILLDIA')
    fails('#<nope>', r'^#<nope> is not defined$', params)
    fails('[1 + #<No Pe>]', r'^#<nope> is not defined$', params)
    fails('#<abc', r"^#<abc: '>' missing after the parameter name$")
    fails('#<  >', r'^#<  >: empty parameter name$')


def test_named_scoping_through_subroutine_levels():
    params = Parameters()
    params.set('x', 1.0)          # local of the main program
    params.set('_g', 2.0)         # global
    params.push_locals()          # o<sub> call
    assert not params.exists('x')                  # the caller's locals are not visible
    fails('#<x>', r'#<x> is not defined', params)
    assert value('#<_g>', params) == 2.0
    params.set('x', 5.0)                            # the sub's own local
    params.set('_g', 3.0)                           # globals set in a sub reach the caller
    params.push_locals()                            # a nested call
    assert not params.exists('x') and value('#<_g>', params) == 3.0
    params.pop_locals()
    assert value('#<x>', params) == 5.0
    params.pop_locals()                             # endsub: the sub's locals vanish
    assert value('#<x>', params) == 1.0
    assert value('#<_g>', params) == 3.0


def test_subroutine_arguments_1_to_30_are_restored():
    params = Parameters({1: 11.0, 30: 13.0, 31: 14.0})
    params.push_locals()
    assert [params.get(k) for k in (1, 5, 30, 31)] == [0.0, 0.0, 0.0, 14.0]   # unused arguments read 0
    params.set(1, 9.0)
    params.set(5, 8.0)
    params.set(30, 7.0)
    params.set(31, 6.0)                              # #31 and above are global
    params.pop_locals()
    assert [params.get(k) for k in (1, 5, 30, 31)] == [11.0, 0.0, 13.0, 6.0]


def test_parameters_api_errors():
    params = Parameters()
    with pytest.raises(RuntimeError, match='pop_locals without a matching push_locals'):
        params.pop_locals()
    with pytest.raises(ExprError, match=r'^#0: parameter number out of range'):
        params.set(0, 1.0)
    with pytest.raises(ExprError, match=r'^#0: parameter number out of range'):
        params.get(0)
    with pytest.raises(ExprError, match=r'^#5400: parameter number out of range'):
        Parameters({5400: 1.0})
    with pytest.raises(ExprError, match='not finite'):
        params.set(1, math.inf)
    with pytest.raises(TypeError):
        params.set(1.5, 1.0)
    with pytest.raises(TypeError):
        params.get(True)
    assert issubclass(ExprError, ValueError)


# --- assignments --------------------------------------------------------------------------

def test_assignment_is_returned_not_applied():
    # "Numbered Parameters": with #3 = 15, '#3=6 G1 X#3' moves to X15 and leaves #3 = 6
    params = Parameters({3: 15.0})
    code = '#3=6 G1 X#3'
    assert read_assignment(code, 0, params) == ((3, 6.0), 4)
    assert read_real(code, 9, params) == (15.0, 11)


@pytest.mark.parametrize('code, expected', [
    ('#<_Endmill Dia> = 0.049', (('_endmilldia', 0.049), 23)),
    ('#<_endmill_rad> = [#<_endmill_dia>/2.0] G1', (('_endmill_rad', 0.125), 39)),
    ('##2 = 5', ((7, 5.0), 7)),
    ('#[1+1]=-.5', ((2, -0.5), 10)),
    ('#  31 =ABS[-3]X1', ((31, 3.0), 14)),
])
def test_assignments(code, expected):
    params = Parameters({2: 7.0})
    params.set('_endmill_dia', 0.25)
    assert read_assignment(code, 0, params) == expected


def test_assignment_errors():
    params = Parameters()
    with pytest.raises(ExprError, match=r"^#5 G: '=' missing in parameter setting"):
        read_assignment('#5 G1', 0, params)
    with pytest.raises(ExprError, match=r'^#0: parameter number 0 out of range'):
        read_assignment('#0=1', 0, params)
    with pytest.raises(ExprError, match=r'^X1: a parameter setting starts with #$'):
        read_assignment('X1', 0, params)
    with pytest.raises(ExprError, match=r'^\[1/0\]: division by zero$'):
        read_assignment('#1=[1/0]', 0, params)
    with pytest.raises(ExprError, match=r'^#<_nope> is not defined$'):
        read_assignment('#<_a> = #<_nope>', 0, params)


# --- evaluation and syntax errors ---------------------------------------------------------

@pytest.mark.parametrize('text, message', [
    ('[1/0]', '[1/0]: division by zero'),
    ('[2 + [1/0]]', '[1/0]: division by zero'),              # the innermost expression is quoted
    ('[#1 / #2]', '[#1 / #2]: division by zero'),
    ('[5 MOD 0]', '[5 MOD 0]: MOD by zero'),
    ('[-8 ** [1/3]]', '[-8 ** [1/3]]: negative base -8 with non-integer exponent 0.333333'),
    ('[10 ** 400]', '[10 ** 400]: result is not finite (overflow)'),
    ('[#3 * #3]', '[#3 * #3]: result is not finite (overflow)'),
    ('[0 ** -1]', '[0 ** -1]: result is not finite (overflow)'),
    ('EXP[1000]', 'EXP[1000]: result is not finite (overflow)'),
    ('SQRT[-4]', 'SQRT[-4]: square root of a negative number (-4)'),
    ('LN[0]', 'LN[0]: logarithm of a number <= 0 (0)'),
    ('LN[-1]', 'LN[-1]: logarithm of a number <= 0 (-1)'),
    ('ASIN[1.5]', 'ASIN[1.5]: argument outside [-1, 1] (1.5)'),
    ('ACOS[-2]', 'ACOS[-2]: argument outside [-1, 1] (-2)'),
    ('[1 + 2', "[1 + 2: unclosed '[' (']' missing)"),
    ('[1 + [2]', "[1 + [2]: unclosed '[' (']' missing)"),
    ('ABS[1', "ABS[1: unclosed '[' (']' missing)"),
    ('[1]]', "[1]]: unbalanced ']' (no matching '[')"),
    ('5]', "5]: unbalanced ']' (no matching '[')"),
    ('FOO[1]', 'FOO: unknown function (known: ABS ACOS ASIN ATAN COS EXISTS EXP FIX FUP LN ROUND SIN SQRT TAN)'),
    ('[1 + bar[2]]', 'bar: unknown function'),
    ('[1 +]', "[1 +]: missing value before ']'"),
    ('[* 2]', "[* 2]: missing value before '*'"),
    ('[]', "[]: missing value before ']'"),
    ('', '(nothing): missing value at end of line'),
    ('[1 FOO 2]', "[1 FOO 2]: unknown operator 'FOO'"),
    ('ATAN[1]', 'ATAN[1]: ATAN needs two arguments: ATAN[y]/[x]'),
    ('ATAN[1]/2', "ATAN[1]/2: '[' missing after ATAN[y]/"),
    ('ABS 1', "ABS 1: '[' missing after ABS"),
])
def test_error_messages(text, message):
    fails(text, '^' + re.escape(message), Parameters({1: 1.0, 2: 0.0, 3: 1e200}))


def test_long_expressions_quote_the_failing_operation():
    text = '[1 + 2 + 3 + 4 + 5 + 6 + 7 + 8 + 9 + 10 + #1/0]'
    fails(text, r'^#1/0: division by zero$', Parameters({1: 1.0}))
    fails('[SQRT[-1] + 2 + 3 + 4 + 5 + 6 + 7 + 8 + 9 + 10 + 11 + 12]',
          r'^SQRT\[-1\]: square root of a negative number \(-1\)$')


def test_deep_nesting_is_an_error_not_a_crash():
    text = '[' * 3000 + '1' + ']' * 3000
    fails(text, r'expression nested too deeply')
    assert value('[' * 20 + '1' + ']' * 20) == 1.0
