"""A trajectory that starts a few millimetres from where the machine is: taken after a
minimum-jerk approach move (ControllerConfig.start_approach_m), as a CNC's program
starts from wherever the machine is, instead of refused. The case that asks for it: a
machine with leg-length errors, homed on its drives, whose nominal model puts it
millimetres from the home its program was planned from (issue 45's Monte Carlo)."""

import math

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_trajectory.planner import Limits, Line, plan
from pkm_controller.closed_loop import run
from pkm_controller.config import ControllerConfig
from pkm_controller.controller import ControllerCore
from pkm_controller.operator_actions import Action, apply_action, event_summary
from pkm_controller.reference import PEAK_RATE, Reference, check_consistent, minimum_jerk, with_approach
from pkm_controller.tracking import Approach, ReferenceTracker
from pkm_kinematics.task_space import PLANAR, SPATIAL

ARCHI = load_machine("archi")
HOME = ARCHI.model.home.tolist()
LIMITS = Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0), (200.0, 200.0, 800.0))
# ~1 % leg-length errors: the nominal model puts the machine 11.6 mm from home
LEG_ERRORS = (-0.0063, 0.0008, -0.013, -0.0004)


def _line_from_home(dx: float = 0.05) -> Reference:
    samples = plan([Line(tuple(HOME), (HOME[0] + dx, HOME[1], HOME[2]))], LIMITS, translation_axes=2)
    return Reference(samples.time_s, samples.position, samples.velocity, samples.acceleration)


def test_minimum_jerk_rates_are_its_derivatives_and_it_rests_at_both_ends():
    h = 1e-6
    for tau in np.linspace(0.05, 0.95, 19):
        s, ds, dds = minimum_jerk(tau)
        assert ds == pytest.approx((minimum_jerk(tau + h)[0] - minimum_jerk(tau - h)[0]) / (2 * h), abs=1e-7)
        assert dds == pytest.approx((minimum_jerk(tau + h)[1] - minimum_jerk(tau - h)[1]) / (2 * h), abs=1e-6)
    assert minimum_jerk(0.0) == (0.0, 0.0, 0.0) and minimum_jerk(1.0) == (1.0, 0.0, 0.0)
    assert minimum_jerk(0.5)[1] == PEAK_RATE


def test_the_approach_ends_exactly_at_the_start_and_the_whole_is_one_consistent_motion():
    ref = _line_from_home()
    offset = [0.004, -0.003, 0.01]
    out = with_approach(ref, offset, 0.2345, 0.001)
    assert out.time_s[235] == pytest.approx(0.235)            # rounded up to whole cycles
    assert out.position[235] == ref.start and out.time_s[235 + 1] == pytest.approx(0.235 + ref.time_s[1])
    assert np.allclose(out.position[0], np.subtract(ref.start, offset), atol=1e-15)
    assert out.duration_s == pytest.approx(0.235 + ref.duration_s) and out.end == ref.end
    check_consistent(out)                                     # positions, rates and rest at both ends agree
    # the peak speed along the offset: 1.875 |offset| / T
    speed = max(np.hypot(v[0], v[1]) for v in out.velocity[:235])
    assert speed == pytest.approx(PEAK_RATE * math.hypot(0.004, 0.003) / 0.235, rel=1e-3)


def test_a_tracker_starts_within_the_tolerance_approaches_within_the_bounds_and_refuses_beyond():
    approach = Approach(0.02, 0.1, 0.02, 0.1, 10.0, 50.0, 0.0, 0.001)      # the speeds bind here
    tracker = ReferenceTracker(PLANAR, 0.005, 0.04, approach=approach)
    ref = _line_from_home()
    near = [HOME[0] - 0.003, HOME[1], HOME[2]]
    assert tracker.starting(ref, near) == (ref, None)
    far = [HOME[0] - 0.012, HOME[1] + 0.005, HOME[2] - 0.08]
    taken, how = tracker.starting(ref, far)
    dist = math.hypot(0.012, 0.005)
    assert how["distance_m"] == pytest.approx(dist) and how["angle_rad"] == pytest.approx(0.08)
    # the slower of the two: the rotation, 1.875 * 0.08 / 0.1 = 1.5 s (the translation's 1.22 s)
    assert how["duration_s"] == pytest.approx(1.5) and taken.duration_s == pytest.approx(1.5 + ref.duration_s)
    assert np.allclose(taken.start, far, atol=1e-15)
    too_far = [HOME[0] - 0.021, HOME[1], HOME[2]]
    with pytest.raises(ValueError, match="21.000 mm .*start_tolerance_m 0.005.* start_approach_m 0.02"):
        tracker.starting(ref, too_far)
    with pytest.raises(ValueError, match="start_approach_m: approach moves are for the 3-DOF machines"):
        ReferenceTracker(SPATIAL, 0.005, 0.04, approach=approach)


def test_a_machine_with_leg_errors_approaches_its_program_and_tracks_it_in_its_model():
    """The nominal model puts the homed machine 11.6 mm from the program's start: refused
    without an approach (test_controller), taken with one. The controller's estimate
    then follows the reference from where the machine is to the program's end without a
    jump; the true tool is off by the model error (what a metrology in the loop removes)."""
    ref = _line_from_home()
    plant = Plant(ARCHI, PlantParameters(link_length_errors=LEG_ERRORS))
    config = ControllerConfig(strategy="computed_torque", start_approach_m=0.02)
    steps = 1100 + int(ref.duration_s * 1000) + 300
    core, log = run(ARCHI, config, plant, steps, reference=ref)
    assert not core.stopped and core.supervisor.faults == [], (core.stop_reason, core.supervisor.faults)
    how = core.tracker.last_approach
    assert how["distance_m"] == pytest.approx(0.0116, abs=1e-4), how
    # the speed binds (0.02 m/s over 11.6 mm: 1.09 s; the acceleration's 0.58 s)
    assert how["duration_s"] == pytest.approx(PEAK_RATE * how["distance_m"] / 0.02, abs=1e-3)
    refs = np.array(log.reference)
    steps_of_ref = np.hypot(*np.diff(refs[:, :2], axis=0).T)
    n_approach = round(how["duration_s"] / 0.001)
    # no jump: the approach at most its peak speed a cycle, then the line's 0.5 m/s (LIMITS)
    assert steps_of_ref[:n_approach].max() < 0.02 * 0.001 * 1.001, steps_of_ref[:n_approach].max()
    assert steps_of_ref.max() < 0.5 * 0.001 * 1.001, steps_of_ref.max()
    assert np.allclose(refs[-1], ref.end, atol=1e-12)
    assert np.allclose(core.estimator.pose, ref.end, atol=5e-6), core.estimator.pose
    true_off = math.hypot(plant.x[0] - ref.end[0], plant.x[1] - ref.end[1])
    assert 0.005 < true_off < 0.02, true_off                  # the model error, millimetres


def test_an_operator_trajectory_reports_its_approach_in_its_event():
    core = ControllerCore(ARCHI, ControllerConfig(start_approach_m=0.02))
    plant = Plant(ARCHI, PlantParameters())
    out = plant.output()
    core.update(0.0, out.encoder_positions, out.encoder_velocities)
    ref = _line_from_home()
    shifted = Reference(ref.time_s, np.add(ref.position, [0.007, 0.0, 0.0]), ref.velocity, ref.acceleration)
    event = apply_action(core, Action.TRAJECTORY, shifted)
    assert event["ok"] and event["approach"]["distance_m"] == pytest.approx(0.007, abs=1e-5), event
    assert "after an approach of 7.0" in event_summary(event)


def test_a_short_approach_keeps_within_the_acceleration_bound():
    """0.1 mm at 0.05 m/s would take 4 cycles and 35 m/s^2 (a force spike); the
    acceleration bound makes it sqrt(5.77 d / a)."""
    approach = Approach(0.02, 0.1, 0.05, 0.2, 0.2, 1.0, 0.0, 0.001)
    tracker = ReferenceTracker(PLANAR, 0.0, 0.0, approach=approach)
    ref = _line_from_home()
    taken, how = tracker.starting(ref, [HOME[0] - 1e-4, HOME[1], HOME[2]])
    assert how["duration_s"] == pytest.approx(math.ceil(math.sqrt(10 / math.sqrt(3) * 1e-4 / 0.2) / 0.001) * 0.001)
    n = round(how["duration_s"] / 0.001)
    assert max(abs(a[0]) for a in taken.acceleration[:n]) <= 0.2
    assert max(abs(v[0]) for v in taken.velocity[:n]) <= 0.05


def test_a_fixed_approach_gives_every_start_the_same_timing():
    """approach_duration_s: the program starts that long after the trajectory, whether
    the machine was off its start (an approach move), or at it (a hold)."""
    approach = Approach(0.02, 0.1, 0.05, 0.2, 0.2, 1.0, 1.5, 0.001)
    tracker = ReferenceTracker(PLANAR, 0.005, 0.04, approach=approach)
    ref = _line_from_home()
    at_start, how = tracker.starting(ref, list(HOME))
    assert how["distance_m"] == 0.0 and how["duration_s"] == 1.5
    assert all(p == ref.start for p in at_start.position[:1501])
    off, how = tracker.starting(ref, [HOME[0] - 0.012, HOME[1], HOME[2]])
    assert how["duration_s"] == 1.5 and off.time_s == at_start.time_s and off.position[1500:] == ref.position


@pytest.mark.parametrize("field, value, message", [
    ("start_approach_m", 0.003, r"start_approach_m: must be 0 \(off\), or in \[0.005, 0.1\] m"),
    ("start_approach_m", 0.2, r"start_approach_m: must be 0 \(off\), or in \[0.005, 0.1\] m"),
    ("start_approach_rad", 0.6, r"start_approach_rad: must be 0 \(off\), or in \[0.04, 0.5\] rad"),
    ("approach_speed_m_s", 0.0, r"approach_speed_m_s: must be in \[0.001, 1\] m/s"),
    ("approach_speed_rad_s", 3.0, r"approach_speed_rad_s: must be in \[0.001, 2\] rad/s"),
    ("approach_acceleration_m_s2", 20.0, r"approach_acceleration_m_s2: must be in \[0.001, 10\] m/s\^2"),
    ("approach_duration_s", 1.0, r"approach_duration_s: must be 0 without an approach"),
])
def test_approach_settings_out_of_range_name_the_field(field, value, message):
    with pytest.raises(ValueError, match=message):
        ControllerCore(ARCHI, ControllerConfig(**{field: value}))


def test_an_approach_that_would_take_minutes_or_break_its_bounds_is_refused():
    """At 1 mm/s, 0.1 m would take 188 s (188,000 samples built in the controller's
    callback); a fixed duration shorter than the longest approach allows would exceed
    the speed or acceleration."""
    with pytest.raises(ValueError, match=r"approach_speed_m_s: .*start_approach_m \(0.1 m\) within 60 s"):
        ControllerCore(ARCHI, ControllerConfig(start_approach_m=0.1, approach_speed_m_s=0.001))
    with pytest.raises(ValueError, match=r"approach_duration_s: must be 0 \(from the speeds\), or in \[.*, 60\] s"):
        ControllerCore(ARCHI, ControllerConfig(start_approach_m=0.04, approach_duration_s=90.0))
    # 40 mm at 0.05 m/s: 1.5 s
    with pytest.raises(ValueError, match=r"approach_duration_s: must be 0 \(from the speeds\), or in \[1.5, 60\] s"):
        ControllerCore(ARCHI, ControllerConfig(start_approach_m=0.04, approach_speed_m_s=0.05,
                                               approach_acceleration_m_s2=1.0, approach_duration_s=1.0))


def test_an_approach_across_pi_turns_the_short_way_and_a_late_first_point_keeps_its_dwell():
    """A planar machine's angle: from pi - 0.01 to -pi + 0.01 is 0.02 rad, not 2 pi; a
    trajectory whose first point is at 0.1 s still rests there until then."""
    approach = Approach(0.02, 0.1, 0.02, 0.1, 10.0, 50.0, 0.0, 0.001)
    tracker = ReferenceTracker(PLANAR, 0.005, 0.0, approach=approach)
    start = [HOME[0], HOME[1], -math.pi + 0.01]
    ref = Reference([0.1, 0.2], [start, start])
    taken, how = tracker.starting(ref, [HOME[0], HOME[1], math.pi - 0.01])
    assert how["angle_rad"] == pytest.approx(0.02) and how["duration_s"] == pytest.approx(0.375)
    angles = [p[2] for p in taken.position]
    assert math.remainder(angles[0] - (math.pi - 0.01), 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
    assert max(abs(b - a) for a, b in zip(angles, angles[1:])) < 1e-4          # no 2 pi swing
    assert taken.time_s[375:] == pytest.approx([0.375, 0.475, 0.575]) and taken.position[375:] == [start] * 3
    assert all(b > a for a, b in zip(taken.time_s, taken.time_s[1:]))
