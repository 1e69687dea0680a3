"""pkm_trajectory.gcode: the RS274 subset parsed into moves in SI units.

Expected values are worked out by hand in the comments (mm -> m: x 0.001,
inch -> m: x 0.0254, F units/min -> m/s: x unit / 60, C degrees -> rad).
"""

import dataclasses
import math

import pytest

from pkm_trajectory.gcode import GcodeError, Move, parse_gcode

approx = pytest.approx


def same_point(actual, expected):
    assert len(actual) == 3
    assert actual == approx(expected, abs=1e-12)


REPRESENTATIVE = """\
%
(representative program: every supported word)
N10 G21 G90 G17
N20 G0 X10 Y5 Z2          ; rapid, no feed needed
N30 G1 Z-1 F600
N40 X20
N50 G2 X30 Y5 I5 J0
N60 G3 X20 Y5 I-5
N70 G91 G1 X-5 C90
N80 Y2.5 C-45
N90 G4 P0.5
N100 G90 G20 G0 X1 Y1
N110 G1 X2 F10
N120 G3 X3 Y2 I0 J1       (quarter turn counter-clockwise, inches)
N130 M30
%
"""


def test_representative_program():
    moves = parse_gcode(REPRESENTATIVE)
    assert [(m.kind, m.line) for m in moves] == [
        ('rapid', 4), ('linear', 5), ('linear', 6), ('arc', 7), ('arc', 8), ('linear', 9),
        ('linear', 10), ('dwell', 11), ('rapid', 12), ('linear', 13), ('arc', 14)]
    rapid, plunge, line, cw, ccw, inc1, inc2, dwell, rapid_in, line_in, arc_in = moves

    # G21 G90: X10 Y5 Z2 mm
    same_point(rapid.target, (0.010, 0.005, 0.002))
    assert rapid.feed is None and rapid.angles == (None, None, None)
    assert rapid.center is None and rapid.clockwise is None and rapid.dwell_s == 0.0

    # F600 mm/min = 0.6 m / 60 s = 0.01 m/s; only Z changes
    same_point(plunge.target, (0.010, 0.005, -0.001))
    assert plunge.feed == approx(0.01)
    # modal G1 and modal feed
    same_point(line.target, (0.020, 0.005, -0.001))
    assert line.feed == approx(0.01) and line.center is None and line.clockwise is None

    # G2 from (20, 5) with I5 J0: centre (25, 5), radius 5 at both ends
    same_point(cw.target, (0.030, 0.005, -0.001))
    same_point(cw.center, (0.025, 0.005, -0.001))
    assert cw.clockwise is True and cw.feed == approx(0.01) and cw.angles == (None, None, None)
    # G3 from (30, 5) with I-5 (J omitted = 0): centre (25, 5)
    same_point(ccw.target, (0.020, 0.005, -0.001))
    same_point(ccw.center, (0.025, 0.005, -0.001))
    assert ccw.clockwise is False

    # G91: X-5 from x = 20 -> 15; C90 incremental from 0 -> pi/2
    same_point(inc1.target, (0.015, 0.005, -0.001))
    assert inc1.angles[:2] == (None, None) and inc1.angles[2] == approx(math.pi / 2)
    # modal G1 and G91: Y 5 + 2.5 = 7.5; C 90 - 45 = 45 deg
    same_point(inc2.target, (0.015, 0.0075, -0.001))
    assert inc2.angles[2] == approx(math.pi / 4)

    # dwell at the current point, P in seconds
    same_point(dwell.target, (0.015, 0.0075, -0.001))
    assert dwell.dwell_s == 0.5 and dwell.feed is None and dwell.angles == (None, None, None)
    assert dwell.center is None and dwell.clockwise is None

    # G20: X1 Y1 in = 0.0254 m; Z unchanged
    same_point(rapid_in.target, (0.0254, 0.0254, -0.001))
    # F10 in/min = 0.254 m / 60 s
    same_point(line_in.target, (0.0508, 0.0254, -0.001))
    assert line_in.feed == approx(10 * 0.0254 / 60)
    # from (2, 1) in, centre (2, 1 + 1) in, end (3, 2) in: radius 1 in at both ends
    same_point(arc_in.target, (0.0762, 0.0508, -0.001))
    same_point(arc_in.center, (0.0508, 0.0508, -0.001))
    assert arc_in.clockwise is False and arc_in.feed == approx(10 * 0.0254 / 60)


def test_move_is_frozen_and_plain():
    move = parse_gcode('G0 X1')[0]
    assert move == Move('rapid', 1, approx((0.001, 0.0, 0.0)), (None, None, None), None, None, None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        move.kind = 'linear'


def test_a_b_c_angles_in_degrees_absolute_and_incremental():
    moves = parse_gcode('G90 G0 A10 B-20 C30\nG91 G0 A5\nG90 G1 F60 X1 B2', start_angles=(0.1, 0.2, 0.3))
    assert moves[0].angles == approx((math.radians(10), math.radians(-20), math.radians(30)))
    assert moves[1].angles[0] == approx(math.radians(15)) and moves[1].angles[1:] == (None, None)
    assert moves[2].angles[0] is None and moves[2].angles[1] == approx(math.radians(2))
    with pytest.raises(GcodeError, match='line 1: A2: A given twice'):
        parse_gcode('G0 A1 A2')


def test_start_point_and_rotation():
    moves = parse_gcode('G91 G0 X1 C10\nG90 G1 Y2 F60\nC-30', start=(0.1, 0.2, 0.3), start_angles=(0.0, 0.0, 0.5))
    # incremental from the start point and start angle
    same_point(moves[0].target, (0.101, 0.2, 0.3))
    assert moves[0].angles[2] == approx(0.5 + math.radians(10))
    # absolute Y2 mm; X, Z kept; C absent -> None (unchanged)
    same_point(moves[1].target, (0.101, 0.002, 0.3))
    assert moves[1].angles == (None, None, None) and moves[1].feed == approx(0.001)
    # a C-only line under G1 rotates in place; absolute -30 deg
    same_point(moves[2].target, (0.101, 0.002, 0.3))
    assert moves[2].kind == 'linear' and moves[2].angles[2] == approx(math.radians(-30))


def test_modal_motion_and_mode_only_lines():
    moves = parse_gcode('G0 X1\nY2\nG1 F600\nX3\nG2 X5 I1\nX7 I1')
    # "G1 F600" sets the mode and the feed without moving
    assert [(m.kind, m.line) for m in moves] == [('rapid', 1), ('rapid', 2), ('linear', 4),
                                                  ('arc', 5), ('arc', 6)]
    same_point(moves[1].target, (0.001, 0.002, 0.0))
    # modal G2: from (5, 2) with I1 -> centre (6, 2), end (7, 2)
    same_point(moves[4].center, (0.006, 0.002, 0.0))
    assert moves[4].clockwise is True


def test_units_apply_to_the_whole_line_and_feed_is_physical():
    # G20 on the line: X and F in inches
    (m,) = parse_gcode('G20 G1 X1 F10')
    same_point(m.target, (0.0254, 0.0, 0.0))
    assert m.feed == approx(0.0254 * 10 / 60)
    # F is converted when read: switching to G20 later keeps 600 mm/min = 0.01 m/s
    moves = parse_gcode('G21 G1 X1 F600\nG20\nX2')
    assert moves[1].feed == approx(0.01)
    same_point(moves[1].target, (0.0508, 0.0, 0.0))
    # incremental inches after mm
    moves = parse_gcode('G0 X10\nG20 G91 X1')
    same_point(moves[1].target, (0.010 + 0.0254, 0.0, 0.0))


def test_arcs_full_circle_and_one_offset_omitted():
    # only I J under G2: a full circle back to the start
    (m,) = parse_gcode('G2 I5 F100')
    same_point(m.target, (0.0, 0.0, 0.0))
    same_point(m.center, (0.005, 0.0, 0.0))
    assert m.clockwise is True and m.feed == approx(0.1 / 60)
    (m,) = parse_gcode('G3 X0 Y0 J-2 F100', start=(0.0, 0.0, 0.5))
    same_point(m.center, (0.0, -0.002, 0.5))
    assert m.clockwise is False
    # quarter arc, J omitted (= 0): from (10, 0) mm around the origin to (0, 10) mm
    (m,) = parse_gcode('G3 X0 Y10 I-10 F100', start=(0.01, 0.0, 0.0))
    same_point(m.center, (0.0, 0.0, 0.0))
    same_point(m.target, (0.0, 0.01, 0.0))
    # I J stay incremental under G90 and G91
    (m,) = parse_gcode('G91 G2 X10 I5 F100', start=(0.1, 0.0, 0.0))
    same_point(m.center, (0.105, 0.0, 0.0))
    same_point(m.target, (0.110, 0.0, 0.0))
    # a Z word equal to the current Z is not a helix
    (m,) = parse_gcode('G0 Z3\nG2 X10 Z3 I5 F100')[1:]
    same_point(m.target, (0.010, 0.0, 0.003))


def test_arc_end_radius_tolerance():
    # r = 5 mm: tolerance 1e-6 + 1e-4 * 0.005 = 1.5e-6 m
    (m,) = parse_gcode('G2 X10.0005 Y0 I5 J0 F100')   # end radius 5.0005 mm: 0.5 um off
    same_point(m.target, (0.0100005, 0.0, 0.0))
    with pytest.raises(GcodeError, match=r'line 1: G2 I5 J0: end point not on the arc'):
        parse_gcode('G2 X10.002 Y0 I5 J0 F100')      # 2 um off


def test_comments_line_numbers_percent_case_and_spaces():
    text = ('%\n'
            '% (delimiter with a comment)\n'
            'N0010 g0 x 10 y -2.5 (move) z+1. ; trailing comment (with a paren\n'
            '(only a comment)\n'
            '; only a comment\n'
            '\n'
            '   \t \n'
            'G01X.5Y-.25F1200(a;b)\n'
            'G00 X1\n'
            '%\n')
    moves = parse_gcode(text)
    assert [(m.kind, m.line) for m in moves] == [('rapid', 3), ('linear', 8), ('rapid', 9)]
    same_point(moves[0].target, (0.010, -0.0025, 0.001))
    same_point(moves[1].target, (0.0005, -0.00025, 0.001))
    assert moves[1].feed == approx(0.02)                # 1200 mm/min


def test_line_endings_and_empty_program():
    moves = parse_gcode('G0 X1\r\nG0 X2\r\n\r\nG0 X3\rG0 X4')
    assert [m.line for m in moves] == [1, 2, 4, 5]
    assert parse_gcode('') == []
    assert parse_gcode('%\n(nothing)\n%\n') == []


def test_program_end_stops_the_program():
    moves = parse_gcode('G0 X1\nG1 X2 F60 M2\n(comment after the end)\n\n%\n')
    # the move on the M2 line runs before the end
    assert [m.line for m in moves] == [1, 2]


# Every case runs after these 4 lines: the line column counts from the case's first
# line, the messages' own references ("M2 on line 6") are absolute.
HEADER = '%\n(header)\n\nG21\n'


@pytest.mark.parametrize('program,line,fragments', [
    # unsupported words: named, never ignored
    ('G0 X1\nG5 X2', 2, ['G5', 'unsupported G-code']),
    ('M0', 1, ['M0', 'unsupported M-code']),
    ('T-1', 1, ['T-1', 'integer >= 0']),
    ('S-5', 1, ['S-5', '>= 0 rpm']),
    ('G18 G81 R1 Z0 X1 F10', 1, ['G81', 'XY plane']),
    ('G17.1', 1, ['G17.1', 'unsupported G-code']),
    ('G95', 1, ['G95', 'unsupported G-code']),
    ('G-1', 1, ['G-1', 'unsupported G-code']),
    ('G0 X1e3', 1, ['E3', 'unsupported word E']),
    ('G2 X10 I5 K0 F100', 1, ['K0', 'not an offset of the G17 plane']),
    ('G2 X10 R4 F100', 1, ['R4', 'cannot reach the end point']),
    # malformed input
    ('G0 X1.2.3', 1, ['X1.2.3', 'malformed number']),
    ('G0 X', 1, ['X:', 'malformed word']),
    ('G0 X--1', 1, ['X--1', 'malformed number']),
    ('G0 X1 0', 1, ["'0'", 'no letter']),
    ('G0 X1 (unclosed', 1, ["unclosed '('"]),
    ('G0 X1 (a (b) c)', 1, ['nested']),
    ('G0 X1 )', 1, ["')'"]),
    ('#1=[1/0]', 1, ['division by zero']),
    ('/G0 X1', 1, ["'/'", 'block delete']),
    ('G0 % X1', 1, ["'%'"]),
    ('G0 X1 N20', 1, ['N20', 'first word']),
    ('N1.5 G0 X1', 1, ['N1.5', 'integer']),
    # words that conflict on one line
    ('G0 G1 X1', 1, ['G0 and G1', 'two motion codes']),
    ('G0 X1 X2', 1, ['X2', 'twice']),
    ('G0 C1 C2', 1, ['C2', 'twice']),
    ('G1 F100 F200 X1', 1, ['F200', 'twice']),
    ('G20 G21', 1, ['G20 and G21', 'two unit codes']),
    ('G90 G91', 1, ['G90 and G91', 'two distance modes']),
    ('G0 X1 M2 M30', 1, ['M2 and M30', 'two M-codes']),
    # feed
    ('G1 X1', 1, ['G1', 'no feed rate']),
    ('G0 X1\nG1\nX2', 3, ['G1 (modal)', 'no feed rate']),
    ('G4 P1\nG2 I5', 2, ['G2', 'no feed rate']),
    ('F0', 1, ['F0', 'must be > 0']),
    ('G1 X1 F-5', 1, ['F-5', 'must be > 0']),
    # motion modes
    ('X1', 1, ['X1', 'no motion mode']),
    ('G1 X1 I1 F100', 1, ['I1', 'only allowed with G2/G3']),
    # arcs
    ('G2 X10 F100', 1, ['G2', 'without its centre']),
    ('G1 X1 F100\nG2 X2', 2, ['G2', 'without its centre']),
    ('G2 X0 I0 J0 F100', 1, ['G2 I0 J0', 'zero arc radius']),
    ('G2 X10 Y0 I3 F100', 1, ['G2 I3', 'end point not on the arc']),
    ('G3 X10 I4 J1 F100', 1, ['G3 I4 J1', 'end point not on the arc']),
    ('G2 X0 R5 F100', 1, ['R5', 'cannot end where it starts']),
    # dwell
    ('G4', 1, ['G4', 'needs P']),
    ('G4 P-1', 1, ['P-1', '>= 0']),
    ('G0 X1 P1', 1, ['P1', 'only allowed with G4']),
    ('G4 P1 X1', 1, ['X1', 'dwell']),
    ('G4 G1 P1', 1, ['G4 and G1', 'dwell']),
    # program end
    ('G0 X1\nM2\nG1 X2 F100', 3, ['G1', 'after program end', 'M2 on line 6']),
    ('M30\n(ok)\n\nN5 X1', 4, ['X1', 'after program end', 'M30 on line 5']),
    ('M2\nG21', 2, ['G21', 'after program end']),
])
def test_errors_name_line_and_word(program, line, fragments):
    with pytest.raises(GcodeError) as info:
        parse_gcode(HEADER + program)
    expected_line = line + HEADER.count('\n')
    err = info.value
    assert isinstance(err, ValueError)
    assert err.line == expected_line
    assert str(err).startswith(f'line {expected_line}: ')
    for fragment in fragments:
        assert fragment in str(err)


def test_argument_checks():
    with pytest.raises(ValueError, match='start'):
        parse_gcode('G0 X1', start=(0.0, 0.0))
    with pytest.raises(ValueError, match='start'):
        parse_gcode('G0 X1', start=(0.0, math.nan, 0.0))
    with pytest.raises(ValueError, match='start_angles'):
        parse_gcode('G0 X1', start_angles=(0.0, math.inf, 0.0))
    with pytest.raises(TypeError, match='text'):
        parse_gcode(b'G0 X1')


def generated_program(n_lines):
    """Line 1 sets up; then alternating G2/G3 half circles of radius 5 mm along +x."""
    lines = ['G21 G90 G17 G1 F1200']
    for k in range(1, n_lines):
        lines.append(f'N{k} G{2 + k % 2} X{10 * k} Y0 I5 J0')
    return '\n'.join(lines) + '\n'


def test_thousand_line_program():
    moves = parse_gcode(generated_program(1000))
    assert len(moves) == 999
    for k, m in enumerate(moves, start=1):
        assert m.line == k + 1 and m.kind == 'arc'
        assert m.clockwise is (k % 2 == 0)                  # G2 for even k
        same_point(m.target, (0.010 * k, 0.0, 0.0))
        same_point(m.center, (0.010 * k - 0.005, 0.0, 0.0))
        assert m.feed == approx(0.02)
    # an error at the very end still names its line
    with pytest.raises(GcodeError, match=r'^line 1001: G5: '):
        parse_gcode(generated_program(1000) + 'G5\n')


# ---- path control: G61 / G64 (LinuxCNC's blend-test programs start "G20 G90 G64 ...")

def test_g64_p_sets_the_blending_tolerance_of_the_moves_that_follow_and_g61_stops_them():
    moves = parse_gcode("G21 G1 F600 X1\nG64 P0.05\nX2\nG20 G64 P0.001 X0.1\nG61\nY1\nG64\nY2\nM2")
    assert [m.blend_tolerance for m in moves] == [None, 5e-5, pytest.approx(0.001 * 0.0254), 0.0, None]


def test_a_linuxcnc_blend_program_header_is_accepted():
    moves = parse_gcode("%\nG20 G90 G64 P0.0005 G40 G17\nG1 F60 X0.5\nY0.5\nX0\nY0\nM2\n%")
    assert len(moves) == 4 and all(m.blend_tolerance == pytest.approx(0.0005 * 0.0254) for m in moves)


@pytest.mark.parametrize("text, message", [
    ("G64 P-1", r"line 1: P-1: G64 blending tolerance must be >= 0"),
    ("G61 P1", r"line 1: P1: P is not allowed with G61"),
    ("G4 G64 P1", r"line 1: G4 and G64: P would be both a dwell and a blending tolerance"),
    ("G61 G64", r"line 1: G61 and G64: two path control modes on one line"),
    ("G64 P0.1 Q0.05", r"line 1: Q0.05: Q is only allowed with G83"),
    ("G61.1", r"line 1: G61.1: exact path mode is not supported"),
    ("G41 D1", r"line 1: G41: cutter compensation is not supported"),
    ("G1 F10 X1 P2", r"line 1: P2: P is only allowed with G4 \(dwell\), G64"),
    ("G1 F10 X1\no100 sub", r"line 2: O100 sub: no endsub for this sub"),
])
def test_path_control_words_it_cannot_honour_are_refused_with_line_and_word(text, message):
    with pytest.raises(GcodeError, match=message):
        parse_gcode(text)
