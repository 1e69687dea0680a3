"""The graph on virtual CANopen drives (hardware: canopen): archi_canopen (archi_demo
at 500 Hz) with the drive interface (drives_node) in sim_hw's place and the virtual
drives (virtual_drives_node) moving the simulated ARCHI, in one process and as
processes: tracked as the same scenario on sim_hw (within 10 %), replayed bit for
bit, the drives' CiA 402 states in the bag; each drive fault through the bus stops
the machine with its cause and drive named, within a cycle."""

import pytest

from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
from pkm_runs.replay import recorded_messages, replay_controller

STEPS = 2478                      # archi_canopen: 4.956 s at 500 Hz


def _commands(run_dir) -> dict:
    return {c.header.stamp.sec * 10**9 + c.header.stamp.nanosec: list(c.effort)
            for _, _, c in recorded_messages(run_dir / "bag", "/pkm", ("drives/command",))}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("canopen")
    bus = run_scenario(load_scenario("archi_canopen"), root / "canopen", in_process=True, progress=False)
    sim = run_scenario(load_scenario("archi_canopen", {"hardware": "sim", "drives": {}}), root / "sim",
                       in_process=True, progress=False)
    return root, bus, sim


def test_archi_on_virtual_canopen_drives_tracks_as_on_sim_hw(runs):
    root, bus, sim = runs
    assert bus["status"] == sim["status"] == "completed", (bus["error"], sim["error"])
    drives = bus["summaries"]["drives"]
    assert drives["steps"] == STEPS and not drives["stopped"] and "sim_hw" not in bus["summaries"]
    assert bus["metrics"]["messages"]["lost_total"] == 0
    b, s = bus["metrics"]["tracking_error"], sim["metrics"]["tracking_error"]
    figures = f"rms {b['rms_m'] * 1e6:.2f} vs {s['rms_m'] * 1e6:.2f} um, max {b['max_m'] * 1e6:.2f} vs " \
              f"{s['max_m'] * 1e6:.2f} um"
    assert b["rms_m"] <= 1.1 * s["rms_m"] and b["max_m"] <= 1.1 * s["max_m"], figures
    assert s["rms_m"] > 5e-6, "a motion under load, not a machine at rest"


def test_the_run_on_drives_replays_bit_for_bit(runs):
    root, bus, _ = runs
    result = replay_controller(root / "canopen")
    assert result.ok and result.identical == result.compared == STEPS + 1 and result.max_abs_diff_n == 0.0


def test_the_bag_shows_each_drive_switched_on_then_enabled(runs):
    root, _, _ = runs
    seen = []
    for _, _, msg in recorded_messages(root / "canopen" / "bag", "/pkm", ("drives/cia402",)):
        seen.append(tuple((st.name, st.message) for st in msg.status))
    names = ("q1", "q2", "q3", "q4")
    assert seen[0] == tuple((n, "switched on") for n in names), seen[0]
    for _, _, msg in recorded_messages(root / "canopen" / "bag", "/pkm", ("drives/cia402",)):
        homing = [{kv.key: kv.value for kv in st.values}["homing"] for st in msg.status]
        assert homing == ["homed (method 19)"] * 3 + ["homed (method 35)"], homing    # the homing, recorded
        break
    assert tuple((n, "operation enabled") for n in names) in seen, seen


def test_the_hexapod_on_six_virtual_drives_tracks_as_on_sim_hw(tmp_path):
    """genhexkins at 400 Hz (six drives: 2005 bits a cycle), its RPDOs acting on arrival."""
    bus = run_scenario(load_scenario("hexapod_canopen"), tmp_path / "canopen", in_process=True, progress=False)
    sim = run_scenario(load_scenario("hexapod_canopen", {"hardware": "sim", "drives": {}}), tmp_path / "sim",
                       in_process=True, progress=False)
    assert bus["status"] == sim["status"] == "completed", (bus["error"], sim["error"])
    b, s = bus["metrics"]["tracking_error"], sim["metrics"]["tracking_error"]
    figures = f"rms {b['rms_m'] * 1e6:.2f} vs {s['rms_m'] * 1e6:.2f} um, max {b['max_m'] * 1e6:.2f} vs " \
              f"{s['max_m'] * 1e6:.2f} um, rotation rms {b['rotation_rms_rad'] * 1e6:.2f} vs " \
              f"{s['rotation_rms_rad'] * 1e6:.2f} urad"
    assert b["rms_m"] <= 1.1 * s["rms_m"] and b["max_m"] <= 1.1 * s["max_m"], figures
    assert b["rotation_rms_rad"] <= 1.15 * s["rotation_rms_rad"], figures
    assert replay_controller(tmp_path / "canopen").ok


@pytest.mark.slow
def test_processes_over_the_loopback_bridge_compute_the_same_run(runs):
    root, _, _ = runs
    run = run_scenario(load_scenario("archi_canopen"), root / "processes", in_process=False, progress=False)
    assert run["status"] == "completed", run["error"]
    assert run["lost"] and all(v == 0 for v in run["lost"].values()), run["lost"]
    a, b = _commands(root / "canopen"), _commands(root / "processes")
    assert len(a) == STEPS + 1 and a == b


@pytest.mark.slow
def test_the_hexapod_homed_and_run_as_processes_computes_the_same_run(tmp_path):
    runs = {mode: run_scenario(load_scenario("hexapod_canopen"), tmp_path / mode, in_process=mode == "one",
                               progress=False) for mode in ("one", "processes")}
    assert all(r["status"] == "completed" for r in runs.values()), {m: r["error"] for m, r in runs.items()}
    assert runs["processes"]["summaries"]["drives"]["homing"].startswith("homed in")
    a, b = _commands(tmp_path / "one"), _commands(tmp_path / "processes")
    assert len(a) > 1000 and a == b

