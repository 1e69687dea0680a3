"""pkm_trajectory.tool_table: LinuxCNC's tool.tbl read into SI units.

Expected values by hand: mm -> m x 0.001, inch -> m x 0.0254, degrees -> rad x pi/180.
"""

import math
import pickle

import pytest

from pkm_trajectory.tool_table import Tool, ToolTableError, load_tool_table, parse_tool_table

approx = pytest.approx

# LinuxCNC docs, "Tool Compensation" > "Tool Table Format" (docs/src/gcode/tool-compensation.adoc):
# the example rows of the format table, one word per column, a ';' remark at the end.
DOCS_SAMPLE = """\
;
T1 P17 X0 Y0 Z0 A0 B0 C0 U0 V0 W0 D0 I0 J0 Q0 ;rem
T2 P5 X0 Y0 Z0 A0 B0 C0 U0 V0 W0 D0 I0 J0 Q0 ;rem
T3 P12 X0 Y0 Z0 A0 B0 C0 U0 V0 W0 D0 I0 J0 Q0 ;rem
"""

# LinuxCNC's sample lathe table (configs/sim/lathe.tbl, an inch machine), as shipped.
LATHE_SAMPLE = """\
T1 P1 D0.100000 Z+0.100000 I+95.000000 J+155.000000 Q1 ;
T2 P2 D0.100000 I+85.000000 J+25.000000 Q2 ;
T3 P3 D0.100000 I+275.000000 J+335.000000 Q3 ;
T4 P4 D0.100000 I+265.000000 J+205.000000 Q4 ;
T5 P5 D0.100000 I+210.000000 J+150.000000 Q5 ;
T6 P6 D0.100000 X+0.500000 Z+0.500000 I+120.000000 J+60.000000 Q6 ;
T7 P7 D0.100000 I-30.000000 J+30.000000 Q7 ;
T8 P8 D0.100000 I+240.000000 J+300.000000 Q8 ;
T9 P9 D0.100000 Q9 ;
T10 P10 D0. ; demo zero diameter
"""


def test_docs_sample():
    tools = parse_tool_table(DOCS_SAMPLE)
    assert list(tools) == [1, 2, 3]
    assert [t.pocket for t in tools.values()] == [17, 5, 12]
    assert [t.line for t in tools.values()] == [2, 3, 4]
    for t in tools.values():
        assert isinstance(t, Tool)
        assert t.offsets == {a: 0.0 for a in 'XYZABCUVW'}
        assert t.diameter == 0.0 and t.comment == 'rem' and t.length_m == 0.0
        assert (t.front_angle_deg, t.back_angle_deg, t.orientation) == (0.0, 0.0, 0)


def test_lathe_sample_in_inches():
    tools = parse_tool_table(LATHE_SAMPLE, unit=0.0254)
    assert list(tools) == list(range(1, 11))
    t1, t6, t7, t10 = tools[1], tools[6], tools[7], tools[10]
    assert t1.offsets == {'Z': approx(0.00254)} and t1.length_m == approx(0.00254)
    assert t1.diameter == approx(0.00254) and t1.comment == ''
    assert (t1.front_angle_deg, t1.back_angle_deg, t1.orientation) == (95.0, 155.0, 1)
    assert t6.offsets == {'X': approx(0.0127), 'Z': approx(0.0127)}
    assert (t7.front_angle_deg, t7.back_angle_deg) == (-30.0, 30.0)
    assert tools[2].offsets == {} and tools[2].length_m == 0.0
    assert t10.diameter == 0.0 and t10.comment == 'demo zero diameter' and t10.orientation is None


def test_units_mm_default_inch_and_rotary():
    mm = parse_tool_table('T7 P3 Z50.3 X-1.5 W+2 D6 ; 6 mm end mill\n')[7]
    assert mm.offsets == {'X': approx(-0.0015), 'Z': approx(0.0503), 'W': approx(0.002)}
    assert mm.length_m == approx(0.0503) and mm.diameter == approx(0.006)
    assert mm.raw == {'T': 7, 'P': 3, 'Z': 50.3, 'X': -1.5, 'W': 2.0, 'D': 6.0}
    assert mm.comment == '6 mm end mill'
    inch = parse_tool_table('T7 Z2 D.25', unit=0.0254)[7]
    assert inch.length_m == approx(0.0508) and inch.diameter == approx(0.00635)
    rot = parse_tool_table('T1 A90 C-45 Z1e1', unit=0.0254)[1]   # A B C are degrees, not lengths
    assert rot.offsets == {'A': approx(math.pi / 2), 'C': approx(-math.pi / 4), 'Z': approx(0.254)}


def test_layout_freedom():
    text = ('\r\n'
            '; a comment line\r\n'
            '   \t \r\n'
            'z1.5\tt4 d2 ;lower case, tabs; a second ; in the comment, T9 P9\r\n'
            '  T5   ;no pocket, no offsets\n'
            'T6 P0\r'                                       # pocket 0: the spindle (random changers)
            '; end\n')
    tools = parse_tool_table(text)
    assert list(tools) == [4, 5, 6]
    t4 = tools[4]
    assert (t4.line, t4.pocket, t4.length_m, t4.diameter) == (4, None, approx(0.0015), approx(0.002))
    assert t4.comment == 'lower case, tabs; a second ; in the comment, T9 P9'
    assert tools[5].offsets == {} and tools[5].diameter is None and tools[5].comment == 'no pocket, no offsets'
    assert tools[6].pocket == 0 and tools[6].line == 6
    assert parse_tool_table('') == {} and parse_tool_table('; nothing\n\n') == {}


@pytest.mark.parametrize('text, message', [
    ('P1 Z1', "tool table line 1: T: missing: every tool line needs a tool number (P1 ...)"),
    ('T1 Z1\n\nT1 Z2', 'tool table line 3: T1: duplicate tool number (first on line 1)'),
    ('T1 P2\nT2 P2', 'tool table line 2: P2: duplicate pocket number (first on line 1)'),
    ('T0 Z1', "tool table line 1: T0: T0 means 'no tool' in LinuxCNC; tool numbers start at 1"),
    ('T1 D-0.1', 'tool table line 1: D-0.1: negative diameter'),
    ('T1 Zabc', 'tool table line 1: Zabc: not a number'),
    ('T1 Z', 'tool table line 1: Z: not a number'),
    ('T1 Z1.2.3', 'tool table line 1: Z1.2.3: not a number'),
    ('T1 Znan', 'tool table line 1: Znan: not a number'),
    ('T1 Z1e400', 'tool table line 1: Z1e400: not a finite number'),
    ('T1.5', 'tool table line 1: T1.5: T must be an unsigned integer'),
    ('T-1', 'tool table line 1: T-1: T must be an unsigned integer'),
    ('T1 P-2', 'tool table line 1: P-2: P must be an unsigned integer'),
    ('T1 Q1.5', 'tool table line 1: Q1.5: Q must be an unsigned integer'),
    ('T1 Q10', 'tool table line 1: Q10: orientation must be 0..9'),
    ('T1 Z1 z2', 'tool table line 1: z2: Z repeated on the line (first Z1)'),
    ('T1 K3', 'tool table line 1: K3: unknown word (letters are T P X Y Z A B C U V W D I J Q)'),
    ('T1 H1', 'tool table line 1: H1: unknown word (letters are T P X Y Z A B C U V W D I J Q)'),
    # the pre-2.4 column format of LinuxCNC (configs/sim/sim_mm.tbl) has no letters
    ('     1  +11.000000   5.000000  5mm end mill',
     'tool table line 1: 1: unknown word (letters are T P X Y Z A B C U V W D I J Q)'),
])
def test_errors_name_line_and_word(text, message):
    with pytest.raises(ToolTableError) as info:
        parse_tool_table(text)
    assert str(info.value) == message
    assert isinstance(info.value, ValueError)


def test_error_fields_and_pickle():
    with pytest.raises(ToolTableError) as info:
        parse_tool_table('T1\nT2 D-1\n')
    error = info.value
    assert (error.line, error.word, error.reason) == (2, 'D-1', 'negative diameter')
    again = pickle.loads(pickle.dumps(error))
    assert type(again) is ToolTableError and str(again) == str(error) and again.line == 2


@pytest.mark.parametrize('unit', [0, -1e-3, math.nan, math.inf, True, '1e-3', None])
def test_bad_unit(unit):
    with pytest.raises(ValueError, match='unit: must be a positive finite number') as info:
        parse_tool_table('T1 Z1', unit=unit)
    assert not isinstance(info.value, ToolTableError)


def test_load_tool_table(tmp_path):
    path = tmp_path / 'tool.tbl'
    path.write_text(DOCS_SAMPLE + 'T4 P1 Z+12.5 D3 ;probe\n', encoding='utf-8')
    tools = load_tool_table(path)
    assert list(tools) == [1, 2, 3, 4] and tools[4].length_m == approx(0.0125)
    assert load_tool_table(str(path), unit=0.0254)[4].length_m == approx(12.5 * 0.0254)
    path.write_text('T1\nT2 Q11\n', encoding='utf-8')
    with pytest.raises(ToolTableError, match=r'^tool table line 2: Q11: '):
        load_tool_table(path)
