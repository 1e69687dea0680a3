"""What an operator changes in a running controller: the feed override and feed hold
(pkm_controller.feed, against closed forms and finite differences) and the strategy
and gains (ControllerCore.change_settings: the Sliding Star "Projection ON" cures the
ARCHI Fig. 12 fight live; bad settings refused with nothing changed)."""

import math

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_trajectory.planner import Limits, Line, plan
from pkm_controller.closed_loop import run
from pkm_controller.config import ControllerConfig
from pkm_controller.controller import ControllerCore
from pkm_controller.feed import MAX_RATE_PER_S, FeedClock, check_override, scaled_reference
from pkm_controller.reference import Reference

ARCHI = load_machine("archi")
HOME = ARCHI.model.home.tolist()
DT = 0.001


def test_without_an_override_tau_is_t_minus_t0_bit_for_bit():
    clock = FeedClock()
    clock.restart(0.123)
    for k in range(1, 2000):
        t = 0.123 + k * DT
        assert clock.advance(t) == (t - 0.123, 1.0, 0.0)


def test_a_hold_brakes_at_the_bounded_rate_and_a_resume_joins_the_nominal_clock():
    """s ramps 1 -> 0 at MAX_RATE_PER_S: tau gains the area under the ramp, 1 / (2 rate)
    (closed form), then stands still; back at s = 1 tau advances by dt again, exactly."""
    clock = FeedClock()
    ts = [k * DT for k in range(3001)]
    taus = []
    for t in ts:
        if t == ts[200]:
            clock.set_target(0.0)
        if t == ts[1500]:
            clock.set_target(1.0)
        taus.append(clock.advance(t)[0])
    ramp = 1.0 / MAX_RATE_PER_S          # the ramp starts at the last cycle before the change
    assert taus[199 + int(round(ramp / DT))] == pytest.approx(ts[199] + 0.5 * ramp, abs=1e-12)
    assert taus[1499] == pytest.approx(ts[199] + 0.5 * ramp, abs=1e-12)          # held
    assert clock.nominal
    np.testing.assert_allclose(np.diff(taus[-500:]), DT, rtol=0, atol=1e-12)
    assert taus[-1] == pytest.approx(ts[-1] - 2 * 0.5 * ramp - (ts[1500] - ts[200] - ramp), abs=1e-9)


def test_the_scaled_reference_is_the_time_derivative_of_the_sampled_path():
    """v_d = s v(tau) and a_d = s^2 a(tau) + (ds/dt) v(tau) against central differences
    of x_d(t) and v_d(t) on a smooth path, through an override change 1 -> 0.3."""
    tau_grid = np.linspace(0.0, 2.0, 20001)
    x = np.column_stack([0.1 * np.sin(2 * tau_grid), 0.05 * np.cos(3 * tau_grid), 0.2 * tau_grid ** 2])
    v = np.column_stack([0.2 * np.cos(2 * tau_grid), -0.15 * np.sin(3 * tau_grid), 0.4 * tau_grid])
    a = np.column_stack([-0.4 * np.sin(2 * tau_grid), -0.45 * np.cos(3 * tau_grid), 0.4 + 0 * tau_grid])
    ref = Reference(tau_grid, x, v, a)
    clock = FeedClock()
    dt = 1e-4
    xs, vs, as_ = [], [], []
    for k in range(8000):
        if k == 1000:
            clock.set_target(0.3)
        tau, s, sdot = clock.advance(k * dt)
        xd, vd, ad = scaled_reference(ref.sample(tau), s, sdot)
        xs.append(xd), vs.append(vd), as_.append(ad)
    xs, vs, as_ = np.array(xs), np.array(vs), np.array(as_)
    fd_v = (xs[2:] - xs[:-2]) / (2 * dt)
    fd_a = (vs[2:] - vs[:-2]) / (2 * dt)
    ramp_steps = round(0.7 / MAX_RATE_PER_S / dt)
    inner = [k for k in range(1, 7999) if abs(k - 1000) > 2 and abs(k - 1000 - ramp_steps) > 2]   # off the kinks
    np.testing.assert_allclose(fd_v[np.array(inner) - 1], vs[inner], atol=2e-4)
    np.testing.assert_allclose(fd_a[np.array(inner) - 1], as_[inner], atol=2e-3)
    assert clock.scale == pytest.approx(0.3)


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), "fast", None])
def test_an_override_out_of_range_is_refused_with_its_range(bad):
    with pytest.raises(ValueError, match=r"feed_override: must be .*\[0, 1\]"):
        check_override(bad)


def archi_loop(strategy, steps, reference=None, plant_params=None, on_cycle=None, **config):
    plant = Plant(ARCHI, plant_params or PlantParameters(force_limit_n=2000.0))
    core = ControllerCore(ARCHI, ControllerConfig(strategy=strategy, force_limit_n=2000.0, **config))
    return run(ARCHI, core, plant, steps, reference=reference, on_cycle=on_cycle)


def test_a_feed_hold_stops_the_machine_on_its_path_and_a_resume_finishes_it():
    """ARCHI, computed torque, a 60 mm line along x: a hold at 30 % of it brings the tool
    to rest on the line (|y| error < 20 um, moving < 2 um in its last 0.3 s) and the controller stays
    'tracking' (paused); the resume ends at the planned end pose."""
    end = [HOME[0] + 0.06, HOME[1], HOME[2]]
    samples = plan([Line(tuple(HOME), tuple(end))], Limits((0.5, 0.5, 2.0), (5.0, 5.0, 20.0),
                                                         (200.0, 200.0, 800.0)), 1000.0)
    ref = Reference(samples.time_s, samples.position, samples.velocity, samples.acceleration)
    hold_at, resume_at = int(0.3 * samples.duration_s / DT), int(0.3 * samples.duration_s / DT) + 1500
    modes = {}

    def operator(k, core, out):
        if k == hold_at:
            core.feed.set_target(0.0)
        if k == resume_at - 1:
            modes["paused"] = core.mode
            modes["tool"] = list(out.tool_pose)
            core.feed.set_target(1.0)
    steps = resume_at + int(samples.duration_s / DT) + 500
    core, log = archi_loop("computed_torque", steps, ref, on_cycle=operator)
    assert not core.stopped, core.stop_reason
    assert modes["paused"] == "tracking"
    assert HOME[0] + 0.001 < modes["tool"][0] < end[0] - 0.001
    assert abs(modes["tool"][1] - HOME[1]) < 2e-5
    assert np.ptp(np.array(log.tool)[resume_at - 300:resume_at, :2], axis=0).max() < 2e-6   # at rest
    reference = np.array(log.reference)
    assert np.ptp(reference[resume_at - 700:resume_at, 0]) == 0.0    # the reference stood still
    np.testing.assert_allclose(reference[-1], end, atol=1e-12)
    assert core.mode == "holding"


def test_projection_on_while_running_ends_the_fight_of_fig12():
    """ARCHI Fig. 12: joint PIDs with a 2 % leg error fight (internal force near the
    drive limit). Switching to the projected PIDs (Sliding Star eq. 8, "Projection ON"
    of its Fig. 12 panel) while running: the internal force falls below 1 % of the limit."""
    params = PlantParameters(force_limit_n=2000.0, link_length_errors=(0.02, 0.0, 0.0, 0.0))
    seen = {}

    def operator(k, core, out):
        if k == 300:
            seen["before"] = out.internal_force_norm
            assert core.change_settings({"strategy": "decentralized_projected"}) == \
                {"strategy": "decentralized_projected"}
    core, log = archi_loop("joint_pid", 1500, plant_params=params, on_cycle=operator, saturation_trip_s=0.0)
    assert not core.stopped, core.stop_reason
    assert seen["before"] > 0.5 * 2000.0
    assert max(log.internal_force_norm_n[900:]) < 0.01 * 2000.0
    assert core.status()[2]["strategy"] == "decentralized_projected"


@pytest.mark.parametrize("changes, message", [
    ({"bandwidth_hz": 1000.0}, r"bandwidth_hz: must be in \(0, 100\] Hz"),
    ({"strategy": "sensor_space"}, r"strategy: sensor_space feeds back struts"),
    ({"force_limit_n": 10.0}, r"force_limit_n: cannot be changed while running"),
    ({"damping_ratio": True}, r"damping_ratio: must be a number"),
    ({"distribution": "magic"}, r"distribution: must be one of"),
    ({}, r"settings: expected a non-empty mapping"),
])
def test_bad_settings_are_refused_and_nothing_changes(changes, message):
    core = ControllerCore(ARCHI, ControllerConfig(strategy="computed_torque"))
    before = (core.config, core.strategy, core.tuned.gains, core.tuned.task_kp)
    with pytest.raises(ValueError, match=message):
        core.change_settings(changes)
    assert (core.config, core.strategy, core.tuned.gains, core.tuned.task_kp) == before


def test_new_gains_scale_like_a_start_with_them():
    """A bandwidth changed while running gives the gains a controller started with it has."""
    core = ControllerCore(ARCHI, ControllerConfig(strategy="cartesian_pid"))
    core.change_settings({"bandwidth_hz": 10.0, "damping_ratio": 0.8})
    fresh = ControllerCore(ARCHI, ControllerConfig(strategy="cartesian_pid", bandwidth_hz=10.0, damping_ratio=0.8))
    assert core.tuned.task_kp == fresh.tuned.task_kp and core.tuned.joint_kd == fresh.tuned.joint_kd
    assert math.isclose(core.tuned.gains.kp, (2 * math.pi * 10.0) ** 2)


def test_an_estop_is_applied_at_once_and_recorded_after_the_state_given():
    """The estop as an operator action (pkm_controller.operator_actions): the core stops now,
    and the event names the last answered state, which the replay stops after."""
    from pkm_controller.operator_actions import Action, apply_action
    core = ControllerCore(ARCHI, ControllerConfig(strategy="joint_pid"))
    event = apply_action(core, Action.ESTOP, None, after_ns=4_000_000)
    assert core.stopped and core.stop_reason == "estop" and str(core.stop_cause) == "estop"
    assert event == {"kind": "estop", "after_ns": 4_000_000, "ok": True, "message": ""}
    assert apply_action(core, Action.ESTOP, None)["after_ns"] is None        # before any state


def test_a_safe_stop_is_recorded_with_its_cause_and_replays_from_the_record():
    """The controller's own stop as an event (Action.SAFE_STOP): the first cause is kept;
    the payload read back from the event stops a fresh core the same way; after_ns=None
    given means before the first answer, whatever the core has prepared."""
    from pkm_common.causes import TripCause
    from pkm_controller.operator_actions import Action, apply_action, recorded_payload
    core = ControllerCore(ARCHI, ControllerConfig(strategy="joint_pid"))
    q = ARCHI.model.inverse_kinematics(ARCHI.model.home).tolist()
    core.prepare(4_000_000, q, [0.0] * 4, [0.0] * 4)
    assert not core.stopped and core.last_stamp_ns == 4_000_000
    event = apply_action(core, Action.SAFE_STOP, {"reason": "drives/state: none for 0.5 s",
                                                  "cause": TripCause.WATCHDOG}, after_ns=None)
    assert event == {"kind": "safe_stop", "after_ns": None, "ok": True, "message": "",
                     "reason": "drives/state: none for 0.5 s", "cause": "watchdog"}
    apply_action(core, Action.SAFE_STOP, {"reason": "estop", "cause": "estop"})
    assert core.stop_cause == TripCause.WATCHDOG and core.stop_reason == "drives/state: none for 0.5 s"
    fresh = ControllerCore(ARCHI, ControllerConfig(strategy="joint_pid"))
    apply_action(fresh, Action(event["kind"]), recorded_payload(event))
    assert (fresh.stopped, fresh.stop_cause, fresh.stop_reason) == (True, TripCause.WATCHDOG, core.stop_reason)
