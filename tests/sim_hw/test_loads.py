"""A plant's scheduled loads from load entries (pkm_sim_hw.loads): ramps expanded in the
plant's process, the same steps as given one by one."""

import pytest

from pkm_common.params import ParameterError, ParameterValues
from pkm_kinematics import load_machine
from pkm_sim_hw.loads import profile_entries, ramp_steps
from pkm_sim_hw.parameters import declare_plant


def test_a_ramp_reaches_each_wrench_linearly_from_the_one_before():
    steps = ramp_steps([(0.1, 0.004, (10.0, -20.0, 4.0)), (0.2, 0.0, (0.0, 0.0, 0.0)),
                        (0.3, 0.002, (5.0, 5.0, 5.0))], 0.001)
    # closed form: step k of n goes k/n of the way, one period apart, from the entry's t_s
    want = [(0.1 + (k - 1) * 0.001, tuple(k / 4 * w for w in (10.0, -20.0, 4.0))) for k in range(1, 5)]
    want += [(0.2, (0.0, 0.0, 0.0))] + [(0.3 + (k - 1) * 0.001, (2.5 * k,) * 3) for k in (1, 2)]
    assert [t for t, _ in steps] == pytest.approx([t for t, _ in want], abs=1e-15)
    assert [v for _, w in steps for v in w] == pytest.approx([v for _, w in want for v in w], abs=1e-12)
    assert steps[3][1] == (10.0, -20.0, 4.0) and len(steps) == 7


def _plant(**loads):
    params = ParameterValues({"dt_s": 0.001, "max_load_n": 2000.0, **loads})
    return declare_plant(params, load_machine("mom3"))


def test_the_plant_steps_a_profile_as_the_same_steps_given_one_by_one():
    """load_profile (the scenario's entries) and load_schedule (the steps the scenario
    expanded before): the same schedule, bit for bit."""
    entries = [(0.05, 0.2, [120.0, -80.0, 30.0]), (0.3, 0.05, [0.0, 10.0, 0.0]), (0.5, 0.0, [1.0, 2.0, 3.0])]
    flat = [v for t, ramp, w in entries for v in (t, ramp, *w)]
    steps = [v for t, w in ramp_steps(profile_entries(flat, 3, "load_profile"), 0.001) for v in (t, *w)]
    assert len(steps) == 4 * (200 + 50 + 1)
    by_profile = _plant(load_profile=flat, frame_load_profile=[0.1, 0.0, 5.0, 0.0, 0.0])
    by_steps = _plant(load_schedule=steps, frame_load_schedule=[0.1, 5.0, 0.0, 0.0])
    assert by_profile._schedule_all == by_steps._schedule_all and len(by_profile._schedule_all) == 251
    assert by_profile._frame_schedule_all == by_steps._frame_schedule_all == [(100, [5.0, 0.0, 0.0])]


def test_a_bad_profile_is_refused_naming_it():
    with pytest.raises(ParameterError, match=r"'load_profile': give load_schedule \(steps\) or load_profile"):
        _plant(load_profile=[0.1, 0.0, 1.0, 2.0, 3.0], load_schedule=[0.1, 1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match=r"'load_profile': must hold groups of 5 numbers \[t_s, ramp_s"):
        _plant(load_profile=[0.1, 0.0, 1.0, 2.0])
    with pytest.raises(ParameterError, match=r"'frame_load_profile': ramp_s must be in \[0, 10\] s, got -1"):
        _plant(frame_load_profile=[0.1, -1.0, 1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match=r"'load_profile': fx must be in \[-2000, 2000\] N"):
        _plant(load_profile=[0.1, 0.01, 2500.0, 0.0, 0.0])
    with pytest.raises(ParameterError, match=r"'load_profile': times must be finite, >= 0 and non-decreasing"):
        _plant(load_profile=[0.3, 0.0, 1.0, 2.0, 3.0, 0.1, 0.0, 1.0, 2.0, 3.0])
