"""The G-code of CAM post-processors for LinuxCNC, each feature against LinuxCNC's
documented behaviour (its G-code reference's rules and examples, worked by hand here):
coordinate systems, G92, G53, tool lengths, planes, arcs (centre and radius forms, full
circles, turns, helices), drilling cycles, feed modes, parameters and expressions,
spindle and coolant events; bad programs refused with their line and word."""

import math

import pytest
from pytest import approx

from pkm_kinematics.task_space import POSITION
from pkm_trajectory.gcode import GcodeError, parse_gcode
from pkm_trajectory.program import program_segments
from pkm_trajectory.tool_table import parse_tool_table

TOOLS = parse_tool_table("T1 P1 Z50.0 D6.0 ; 6 mm end mill\nT2 P2 Z75.5 D3.0 ; 3 mm drill\n")


def mm(values):
    return [round(v * 1e3, 6) for v in values]


def targets(text, **kwargs):
    return [(m.kind, mm(m.target)) for m in parse_gcode(text, **kwargs) if m.kind != 'event']


def arc_point(text, u, start=(0.0, 0.0, 0.0)):
    """The planner's arc of a program's last move, at u (mm)."""
    moves = parse_gcode(text, start=start)
    segment = program_segments(moves, POSITION, start)[-1]
    return mm(segment.point(u))


# ------------------------------------------------------------ coordinate systems
def test_g10_l2_sets_a_system_and_g54_g59_select_it():
    text = 'G21 G90\nG10 L2 P1 X10 Y20\nG10 L2 P2 X-5 Z1\nG54 G0 X0 Y0\nG55 G0 X0 Y0\nG59.3 G0 X1\n'
    assert targets(text) == [('rapid', [10.0, 20.0, 0.0]), ('rapid', [-5.0, 0.0, 0.0]), ('rapid', [1.0, 0.0, 0.0])]


def test_g10_l20_makes_the_current_point_the_given_coordinates():
    # at machine X5: "G10 L20 P1 X0" -> the G54 X offset is 5; then X1 is machine 6
    assert targets('G21\nG0 X5\nG10 L20 P1 X0\nG0 X1\n')[-1] == ('rapid', [6.0, 0.0, 0.0])


def test_g10_p0_is_the_active_system_and_incremental_mode_does_not_change_l2():
    text = 'G21\nG56\nG91\nG10 L2 P0 X3\nG90 G0 X0\n'
    assert targets(text)[-1] == ('rapid', [3.0, 0.0, 0.0])


def test_offsets_readable_as_linuxcnc_parameters():
    # G54's X lives in #5221; #5220 is the active system (G55: 2)
    assert targets('G21\nG10 L2 P1 X7\nG55\nG0 X#5221 Y#5220\n')[-1] == ('rapid', [7.0, 2.0, 0.0])


def test_g92_offsets_all_systems_and_g92_1_g92_2_g92_3():
    text = ('G21\nG0 X5\nG92 X0\nG0 X1\n'      # the current point (machine 5) becomes X0: X1 is machine 6
            'G92.2\nG0 X1\n'                     # off, kept: X1 is machine 1
            'G92.3\nG0 X2\n'                     # restored: machine 7
            'G92.1\nG0 X2\n')                    # off and cleared: machine 2
    assert [t[1][0] for t in targets(text)] == [5.0, 6.0, 1.0, 7.0, 2.0]


def test_g53_moves_in_machine_coordinates_for_its_line_only():
    text = 'G21\nG10 L2 P1 X100\nG53 G0 X1\nG0 X1\n'
    assert [t[1][0] for t in targets(text)] == [1.0, 101.0]


@pytest.mark.parametrize('text, fragments', [
    ('G10 L2 X1', ['G10 L2', 'P missing']),
    ('G10 L2 P10 X1', ['P10', '0 (active) or 1-9']),
    ('G10 L1 P1 Z1', ['L1', 'only L2 and L20']),
    ('G10 L2 P1 R30 X1', ['R30', 'rotation of a coordinate system']),
    ('G92', ['G92', 'at least one axis word']),
    ('G53 X1', ['G53', 'needs G0 or G1']),
    ('G91 G53 G0 X1', ['G53', 'incremental']),
    ('G10 L2 P1 G1 X1 F10', ['G10 and G1', 'axis words']),
])
def test_coordinate_errors_name_the_word(text, fragments):
    with pytest.raises(GcodeError) as info:
        parse_gcode('G21\n' + text)
    assert info.value.line == 2 and all(f in str(info.value) for f in fragments), str(info.value)


# ------------------------------------------------------------ tools
def test_tool_change_then_g43_applies_the_tools_length_and_g49_removes_it():
    text = 'G21\nT1 M6\nG43 H1\nG0 Z10\nG43\nT2 M6\nG43\nG0 Z10\nG49\nG0 Z10\n'
    moves = [m for m in parse_gcode(text, tools=TOOLS) if m.kind != 'event']
    assert [m.tool_offset for m in moves] == [(0.0, 0.0, approx(0.05)), (0.0, 0.0, approx(0.0755)), (0, 0, 0)]
    # the spindle is the tip plus the offset: a point machine's Z is 10 + 50 mm
    segments = program_segments(moves[:1], POSITION, (0.0, 0.0, 0.0))
    assert mm(segments[0].end) == [0.0, 0.0, 60.0]


def test_m6_alone_keeps_the_offset_in_force_as_linuxcnc():
    # "The tool length offset is not changed by M6, use G43 after the M6"
    moves = [m for m in parse_gcode('G21\nT1 M6\nG43\nT2 M6\nG0 Z1\n', tools=TOOLS) if m.kind != 'event']
    assert moves[0].tool_offset == (0.0, 0.0, approx(0.05))


def test_g43_1_sets_a_dynamic_offset():
    moves = parse_gcode('G21\nG43.1 Z12.5\nG0 X1\n')
    assert moves[-1].tool_offset == (0.0, 0.0, approx(0.0125))


@pytest.mark.parametrize('text, fragments', [
    ('G43 H7', ['H7', 'tool 7 is not in the tool table']),
    ('T9', ['T9', 'not in the tool table']),
    ('M6', ['M6', 'no tool selected']),
    ('G43.1 Z1 G0 X1', ['G43.1 and G0', 'axis words']),
])
def test_tool_errors_name_the_word(text, fragments):
    with pytest.raises(GcodeError) as info:
        parse_gcode('G21\n' + text, tools=TOOLS)
    assert info.value.line == 2 and all(f in str(info.value) for f in fragments), str(info.value)


def test_events_spindle_coolant_tool_change_in_program_order():
    text = 'G21\nT1 M6\nS12000 M3\nM8\nS8000\nM4\nM5 M9\nM7\n'
    events = [(m.line, m.event[0], dict(m.event[1])) for m in parse_gcode(text, tools=TOOLS) if m.kind == 'event']
    assert events == [
        (2, 'tool_change', {'tool': 1, 'previous': 0}),
        (3, 'spindle', {'direction': 'cw', 'rpm': 12000.0}),
        (4, 'coolant', {'mode': 'flood'}),
        (5, 'spindle', {'direction': 'cw', 'rpm': 8000.0}),          # a new S while it turns
        (6, 'spindle', {'direction': 'ccw', 'rpm': 8000.0}),
        (7, 'spindle', {'direction': 'stop', 'rpm': 8000.0}),
        (7, 'coolant', {'mode': 'off'}),
        (8, 'coolant', {'mode': 'mist'})]


# ------------------------------------------------------------ planes and arcs
def test_g17_g18_g19_clockwise_as_seen_from_the_normal_axis():
    # LinuxCNC: "G2 ... as viewed from the positive end of the axis": G18's plane is (Z, X)
    assert arc_point('G21 G17 G2 X10 Y0 I5 F100', 0.5) == approx([5.0, 5.0, 0.0])
    assert arc_point('G21 G18 G2 X10 Z0 I5 F100', 0.5) == approx([5.0, 0.0, -5.0])
    assert arc_point('G21 G19 G2 Y10 Z0 J5 F100', 0.5) == approx([0.0, 5.0, 5.0])
    assert arc_point('G21 G18 G3 X10 Z0 I5 F100', 0.5) == approx([5.0, 0.0, 5.0])


def test_radius_form_under_and_over_180_degrees():
    # R10 between points 10 mm apart: the centre 8.660 mm off the chord, 60 deg; R-10: 300 deg
    short = parse_gcode('G21 G3 X10 R10 F100')[0]
    long = parse_gcode('G21 G3 X10 R-10 F100')[0]
    assert mm(short.center) == approx([5.0, 8.660254, 0.0]) and short.sweep == approx(math.pi / 3)
    assert mm(long.center) == approx([5.0, -8.660254, 0.0]) and long.sweep == approx(5 * math.pi / 3)
    g2 = parse_gcode('G21 G2 X10 R10 F100')[0]
    assert mm(g2.center) == approx([5.0, -8.660254, 0.0]) and g2.sweep == approx(-math.pi / 3)


def test_full_circles_turns_and_helices():
    full = parse_gcode('G21 G2 I5 F100')[0]
    assert full.sweep == approx(-2 * math.pi)
    assert parse_gcode('G21 G3 X10 I5 P2 F100')[0].sweep == approx(3 * math.pi)    # 180 deg and one more turn
    # a helix: Z moves linearly with the angle, half way at half the sweep
    assert arc_point('G21 G3 X0 Y0 Z-3 I5 F100', 0.5) == approx([10.0, 0.0, -1.5])
    assert arc_point('G21 G18 G2 X0 Z0 Y4 K5 P2 F100', 0.25) == approx([0.0, 1.0, 10.0])   # 2 turns, Y 4 mm


def test_g90_1_centre_in_absolute_coordinates():
    assert mm(parse_gcode('G21 G0 X10\nG90.1 G2 X20 I15 J0 F100')[-1].center) == [15.0, 0.0, 0.0]


# ------------------------------------------------------------ canned cycles
def test_g81_absolute_g98_retracts_to_the_old_z():
    # LinuxCNC's G81 example: from X1 Y2 Z3, "G90 G98 G81 X4 Y5 Z1.5 R2.8"
    text = 'G21\nG0 X1 Y2 Z3\nG90 G98 G81 X4 Y5 Z1.5 R2.8 F100\n'
    assert targets(text)[1:] == [('rapid', [4, 5, 3]), ('rapid', [4, 5, 2.8]), ('linear', [4, 5, 1.5]),
                                 ('rapid', [4, 5, 3])]


def test_g81_incremental_with_repeats():
    # LinuxCNC: from Z3, "G91 G98 G81 X4 Y5 Z-0.6 R1.8 L3": R at 4.8, bottom 4.2; the old Z
    # (3) is below R, so it retracts to R; the preliminary move to R happens once
    text = 'G21\nG0 X1 Y2 Z3\nG91 G98 G81 X4 Y5 Z-0.6 R1.8 L3 F100\n'
    moves = targets(text)[1:]
    assert moves[0] == ('rapid', [1, 2, 4.8])
    holes = [m[1][:2] for m in moves if m[0] == 'linear']
    assert holes == [[5, 7], [9, 12], [13, 17]]
    assert all(m[1][2] == approx(4.2) for m in moves if m[0] == 'linear')
    assert moves[-1] == ('rapid', [13, 17, 4.8])


def test_g99_g82_dwell_and_the_cycle_repeats_on_the_next_xy_line():
    text = 'G21\nG0 Z10\nG99 G82 X1 Y1 Z-2 R1 P0.5 F100\nX2\nG80\nG0 X0\n'
    moves = parse_gcode(text)
    # the second hole starts at R: no rapid to R ("if it is not already at the R position")
    assert [m.kind for m in moves[1:]] == ['rapid', 'rapid', 'linear', 'dwell', 'rapid', 'rapid', 'linear', 'dwell',
                                           'rapid', 'rapid']
    assert [m.dwell_s for m in moves if m.kind == 'dwell'] == [0.5, 0.5]
    assert mm(moves[5].target) == [1, 1, 1]        # G99: back to R


def test_g83_pecks_back_to_r_between_pecks():
    text = 'G21\nG0 Z5\nG83 X0 Y0 Z-5 R2 Q2 F100\n'
    z = [(m.kind[0], round(m.target[2] * 1e3, 3)) for m in parse_gcode(text)[2:]]
    assert z == [('r', 2.0), ('l', 0.0), ('r', 2.0), ('r', 0.254), ('l', -2.0), ('r', 2.0), ('r', -1.746),
                 ('l', -4.0), ('r', 2.0), ('r', -3.746), ('l', -5.0), ('r', 5.0)]


@pytest.mark.parametrize('text, fragments', [
    ('G81 X1 Z-1 F100', ['G81', 'R (the retract plane) is missing']),
    ('G81 X1 R-2 Z-1 F100', ['G81', 'R plane', 'below the bottom']),
    ('G83 X1 R1 Z-1 F100', ['G83', 'Q missing']),
    ('G81 X1 R1 Z-1 L0 F100', ['L0', 'integer >= 1']),
    ('G93 G81 X1 R1 Z-1 F100', ['G81', 'inverse time']),
    ('G80 X1', ['X1', 'G80']),
    ('G81 X1 R1 Z-1 A5 F100', ['A5', 'rotary']),
])
def test_cycle_errors_name_the_word(text, fragments):
    with pytest.raises(GcodeError) as info:
        parse_gcode('G21\n' + text)
    assert info.value.line == 2 and all(f in str(info.value) for f in fragments), str(info.value)


# ------------------------------------------------------------ feed modes
def test_g93_inverse_time_feed():
    # F60 under G93: the move takes 1/60 min = 1 s: 10 mm in 1 s
    moves = parse_gcode('G21\nG93 G1 X10 F60\n')
    assert moves[0].feed == approx(0.010)
    with pytest.raises(GcodeError, match='line 3: G1: inverse time feed .*F is required'):
        parse_gcode('G21\nG93 G1 X10 F60\nX20\n')
    with pytest.raises(GcodeError, match='line 3: G1: no feed rate'):     # G94 after G93 needs a new F
        parse_gcode('G21\nG93 G1 X10 F60\nG94 G1 X20\n')


# ------------------------------------------------------------ parameters and expressions
def test_parameters_and_expressions():
    text = ('G21\n#1 = 5\n#<depth> = [-#1 / 2]\nG1 X[#1 * 2] Y[ATAN[1]/[1] + SQRT[16]] Z#<depth> F[100 * 6]\n'
            '#3 = 6 G0 X#3\n')
    moves = parse_gcode(text)
    assert mm(moves[0].target) == approx([10.0, 49.0, -2.5]) and moves[0].feed == approx(0.010)
    assert mm(moves[1].target)[0] == 0.0       # a setting takes effect after the line's reads


@pytest.mark.parametrize('text, fragments', [
    ('G1 X[1/0] F10', ['X[1/0]', 'division by zero']),
    ('#1 = [2 * [3]', ['unclosed']),
    ('G0 X#<nope>', ['#<nope> is not defined']),
    ('o100 sub', ['O100 sub', 'no endsub']),
    ('o100 if [1]\nG0 X1', ['O100 if', 'no endif']),
])
def test_expression_errors_name_the_word(text, fragments):
    with pytest.raises(GcodeError) as info:
        parse_gcode('G21\n' + text)
    assert info.value.line == 2 and all(f in str(info.value) for f in fragments), str(info.value)


def test_a_cam_style_header_is_understood():
    """What a LinuxCNC post-processor writes first (refused before within five lines)."""
    text = ('%\n(T1 D=6 CR=0 - ZMIN=-2 - flat end mill)\nG90 G94 G17 G91.1\nG21\nG53 G0 Z0\n'
            'T1 M6\nS12000 M3\nG54\nM8\nG0 X10 Y10\nG43 Z15 H1\nG0 Z5\nG1 Z-2 F300\nG1 X40 F1200\n'
            'G18 G3 X50 Z-2 I5 K0\nG17 G2 X60 Y20 R10\nG19 G2 Y30 J5 K0\nG17 G98 G81 X70 Y10 Z-5 R2 F150\n'
            'X75\nG80\nM9\nM5\nG53 G0 Z0\nG49\nM30\n%\n')
    moves = parse_gcode(text, tools=TOOLS)
    assert [m.event[0] for m in moves if m.kind == 'event'] == ['tool_change', 'spindle', 'coolant', 'coolant',
                                                                'spindle']
    assert sum(m.kind == 'arc' for m in moves) == 3
    assert moves[-1].target[2] == 0.0 and moves[-1].tool_offset == (0.0, 0.0, approx(0.05))   # G53 before G49


# ------------------------------------------------------------ found in review
def test_g91_cycles_count_r_from_the_initial_level_and_z_from_r():
    # LinuxCNC interp_cycles: under G91, r = R + the initial level, z = r + Z, on every line
    text = 'G21\nG0 Z10\nG91 G99 G81 X5 R-2 Z-3 F100\nX5 R-2 Z-3\nX5\n'
    bottoms = [round(m.target[2] * 1e3, 6) for m in parse_gcode(text) if m.kind == 'linear']
    assert bottoms == [5.0, 5.0, 5.0]


def test_full_circles_stay_full_under_g91_and_g92():
    for text in ('G21\nG10 L2 P1 X16.249 Y8.1245\nG92 X0 Y0\nG2 X0 Y0 I5 F100',
                 'G21\nG10 L2 P1 X34.743\nG91 G2 X0 I5 F100'):
        arc = parse_gcode(text, start=(-0.219381, -6e-05, 0.1))[-1]
        assert arc.sweep == approx(-2 * math.pi), text


def test_coordinate_system_parameters_read_only_and_in_the_programs_unit():
    with pytest.raises(GcodeError, match=r'line 2: #5221: coordinate system data is read-only'):
        parse_gcode('G21\n#5221 = 10\n')
    # G54 X 10 mm read in inches after G20: 0.3937
    assert parse_gcode('G21\nG10 L2 P1 X10\nG20\nG0 X[#5221]\n')[-1].target[0] == approx(0.010 + 0.010)


def test_program_end_and_tool_change_stop_the_spindle():
    events = [(m.line, m.event[0], dict(m.event[1])) for m in
              parse_gcode('G21\nS1000 M3 M8\nT1 M6\nM3\nM30\n', tools=TOOLS) if m.kind == 'event']
    assert [(line, name, data.get('direction', data.get('mode'))) for line, name, data in events] == [
        (2, 'spindle', 'cw'), (2, 'coolant', 'flood'), (3, 'spindle', 'stop'), (3, 'tool_change', None),
        (4, 'spindle', 'cw'), (5, 'spindle', 'stop'), (5, 'coolant', 'off')]


@pytest.mark.parametrize('text, fragments', [
    ('G83 X1 R1 Z-1 Q1 P1 F100', ['P1', 'G82']),
    ('G0 X10\nG90.1 G2 X20 I15 F100', ['G90.1', 'needs both I J']),
    ('G43.1 Z10 A5', ['A5', 'X Y Z only']),
])
def test_words_that_would_be_dropped_are_refused(text, fragments):
    with pytest.raises(GcodeError) as info:
        parse_gcode('G21\n' + text)
    assert all(f in str(info.value) for f in fragments), str(info.value)
