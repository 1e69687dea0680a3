"""The direct engine (pkm_bringup.direct) computes the graph's run: every lockstep
scenario of config/scenarios run by both (the graph's nodes in one process, the
engine's loops without a transport), every command and true pose compared byte for
byte (the CDR bytes of each stamp's first message: the values, the stamp and the
plant's status word), and the run's outcome. Scenarios the engine refuses are
refused by name, nothing started.

Each scenario runs its first ``SECONDS`` of simulated time in both (its program
planned once: planning.PlannerSettings.plan_program keeps it for the second engine);
``tools/golden.py compare --engine direct`` compares whole runs against the golden
outputs the graph recorded.

The bags are written as pkm-run writes them, by a process of their own
(direct_recording.RecorderProcess): pytest's process has threads of its own, which
would otherwise keep the writer in the run's process.
"""

from pathlib import Path

import pytest

from pkm_bringup import direct_recording
from pkm_bringup.direct import refusal
from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
from pkm_common import topics
from pkm_common.cdr import stamp_ns_of
from pkm_runs.replay import recorded_bytes

SCENARIOS = {p.stem: load_scenario(p) for p in
             sorted((Path(__file__).resolve().parents[2] / "config" / "scenarios").glob("*.yaml"))}
LOCKSTEP = [n for n, s in SCENARIOS.items() if s.mode == "lockstep"]
DIRECT = [n for n in LOCKSTEP if not refusal(SCENARIOS[n])]
SECONDS = 0.6


@pytest.fixture(autouse=True)
def _writer_process(monkeypatch):
    monkeypatch.setattr(direct_recording, "may_fork", lambda: True)


def per_stamp(run_dir: Path, namespace: str, topic: str) -> dict[int, bytes]:
    """Each stamp's first message on ``topic`` (the graph repeats the plant's first
    state until its controller answers)."""
    out = {}
    for _, _, raw in recorded_bytes(run_dir / "bag", namespace, (topic,)):
        out.setdefault(stamp_ns_of(raw), bytes(raw))
    return out


def test_the_engine_runs_every_lockstep_scenario_on_the_simulated_machine():
    refused = {n: refusal(SCENARIOS[n]) for n in LOCKSTEP if n not in DIRECT}
    assert set(refused) == {"archi_canopen", "hexapod_canopen"}, refused
    assert all("hardware" in why and "run it as a graph" in why for why in refused.values()), refused
    assert len(DIRECT) >= 20, DIRECT


@pytest.mark.parametrize("name", DIRECT)
def test_the_direct_engine_computes_the_graphs_run_byte_for_byte(name, tmp_path):
    s = load_scenario(name, {"duration_s": SECONDS})
    graph = run_scenario(s, tmp_path / "graph", in_process=True, progress=False, report=False)
    direct = run_scenario(s, tmp_path / "direct", engine="direct", progress=False, report=False)
    assert direct["mode"] == "direct" and graph["mode"] == "in_process"
    assert (direct["status"], direct["cause"]) == (graph["status"], graph["cause"]), (graph["error"], direct["error"])
    assert direct["trip_reason"] == graph["trip_reason"]
    steps = round(SECONDS / s.dt_s)
    for topic in (topics.DRIVES_COMMAND, topics.TRUE_POSE, topics.DRIVES_STATE):
        want = per_stamp(tmp_path / "graph", s.namespace, topic)
        got = per_stamp(tmp_path / "direct", s.namespace, topic)
        assert len(want) >= (steps if graph["cause"] == "none" else 1), (topic, len(want))
        assert sorted(got) == sorted(want), (topic, len(got), len(want), sorted(set(got) ^ set(want))[:5])
        differ = [stamp for stamp in want if got[stamp] != want[stamp]]
        assert not differ, f"{topic}: {len(differ)} of {len(want)} stamps differ, the first at {min(differ)} ns"
    # the run's record: what each node published was recorded, in both
    assert direct["lost"] == {t: 0 for t in direct["published"]}, direct["lost"]
    assert direct["published"] == graph["published"]


def test_a_refused_scenario_starts_nothing(tmp_path):
    run = run_scenario(load_scenario("archi_canopen"), tmp_path / "run", engine="direct", progress=False)
    assert run["status"] == "failed" and "hardware canopen" in run["error"] and "nothing started" in run["error"]
    assert not (tmp_path / "run" / "bag").exists()
    for name in ("panel_archi", "archi_ros2_control"):
        assert "mode realtime" in refusal(SCENARIOS[name]), name
    named = load_scenario("mom3_square", {"operators": ["/pkm/my_script"]})
    assert "operators ['/pkm/my_script']" in refusal(named) and "run it as a graph" in refusal(named)


@pytest.mark.parametrize("name, overrides, reads_pose", [
    ("archi_demo", {}, False), ("hexapod_metrology", {"controller": {"strategy": "measured_space"}}, True)])
def test_a_run_without_a_recording_makes_no_message_nobody_reads(name, overrides, reads_pose, tmp_path,
                                                                 monkeypatch):
    """Unrecorded, the direct engine makes no /clock, no controller/reference or
    controller/status, and no Gough DKM pose unless the controller feeds it back (measured_space does,
    archi_demo's sensor_space reads the struts): the same run
    all the same, every cycle's statistics in the controller's summary and the plant's
    last state."""
    import pkm_sim_hw.step_streams as step_streams
    from pkm_controller.controller import ControllerCore
    made = {"clock": 0, "status": 0}
    real_encode_clock, real_status = step_streams.encode_clock, ControllerCore.status

    def counted(ns):
        made["clock"] += 1
        return real_encode_clock(ns)

    def status(core):
        made["status"] += 1
        return real_status(core)
    monkeypatch.setattr(ControllerCore, "status", status)
    monkeypatch.setattr(step_streams, "encode_clock", counted)
    runs = {}
    for record in (True, False):
        runs[record] = run_scenario(load_scenario(name, {**overrides, "duration_s": 0.3, "record": record}),
                                    tmp_path / str(record), engine="direct", progress=False, report=False)
        made[record], made["clock"], made["status"] = (made["clock"], made["status"]), 0, 0
    recorded, unrecorded = runs[True], runs[False]
    assert recorded["status"] == unrecorded["status"] == "completed", (recorded["error"], unrecorded["error"])
    steps = recorded["summaries"]["sim_hw"]["steps"]
    # (clocks, statuses): the one status left is the summary's (configuration.run_summary)
    assert made[True][0] >= steps and made[True][1] >= 4 and made[False] == (0, 1), made
    sensor, sensor_recorded = unrecorded["summaries"]["gough_sensor"], recorded["summaries"]["gough_sensor"]
    assert sensor["measured"] == sensor_recorded["measured"] >= steps
    assert sensor_recorded["dkm_run"] and sensor_recorded["solved"] == sensor_recorded["measured"]
    assert sensor["dkm_run"] == reads_pose and sensor["solved"] == (sensor["measured"] if reads_pose else 0), sensor
    volatile = ("wall", "compute", "response", "per_s")
    for node in ("controller", "sim_hw"):
        want = {k: v for k, v in recorded["summaries"][node].items() if not any(w in k for w in volatile)}
        got = {k: v for k, v in unrecorded["summaries"][node].items() if not any(w in k for w in volatile)}
        assert len(want) > 10 and got == want, (node, {k: (got.get(k), v) for k, v in want.items() if got.get(k) != v})


@pytest.mark.parametrize("name, overrides", [
    ("archi_demo", {"duration_s": 1.5}),
    # three brakes: the plant holds, the controller trips; the record goes on
    ("mom3_square", {"duration_s": 1.0, "plant": {"faults": "0:locked:0.3,1:locked:0.3,2:locked:0.3"}}),
])
def test_a_run_kept_in_memory_has_the_metrics_of_its_bag(name, overrides, tmp_path):
    """A study's run whose bag would be removed once read keeps its messages in memory
    (pkm_recording.memory) and takes its metrics from them: the metrics read from the
    bag of the same run, every one, and the same record of what was published and
    recorded; no bag written."""
    from pkm_recording.memory import MemoryRecording
    from pkm_runs.report import analyse_bag
    from pkm_runs.report_metrics import metrics_dict
    s = load_scenario(name, {**overrides, "record": True})
    bagged = run_scenario(s, tmp_path / "bag", engine="direct", progress=False, report=False)
    recording = MemoryRecording()
    kept = run_scenario(s, tmp_path / "memory", engine="direct", progress=False, report=False, recording=recording)
    assert not (tmp_path / "memory" / "bag").exists() and len(recording) > 0
    want = metrics_dict(analyse_bag(tmp_path / "bag", namespace=bagged["namespace"], machine_name=bagged["machine"]),
                        bagged["published"])
    got = kept["metrics"]
    assert (got.pop("bag"), want.pop("bag")) == ("memory", str(tmp_path / "bag" / "bag"))
    timing, want_timing = got.pop("timing"), want.pop("timing")      # two runs: their wall clocks differ
    assert sorted(timing) == sorted(want_timing) and timing["sim_s"] == want_timing["sim_s"]
    assert got == want
    assert (kept["recorded"], kept["lost"], kept["status"], kept["cause"]) == \
        (bagged["recorded"], bagged["lost"], bagged["status"], bagged["cause"])
    with pytest.raises(ValueError, match="recording: in memory only for a recorded run"):
        run_scenario(s, tmp_path / "graph", progress=False, recording=MemoryRecording())


def test_a_failed_run_kept_in_memory_leaves_its_bag(tmp_path):
    """A study keeps a failed run's directory to be looked into: its messages are
    written as its bag, which reads back to the metrics taken in memory. (ARCHI with
    1 % leg errors starts 11.6 mm from its program in the nominal model: refused, the
    program did not run.)"""
    from pkm_recording.memory import MemoryRecording
    from pkm_runs.report import analyse_bag
    from pkm_runs.report_metrics import metrics_dict
    s = load_scenario("archi_demo", {"duration_s": 0.5, "record": True, "metrology": False,
                                     "controller": {"strategy": "computed_torque"},
                                     "plant": {"link_length_errors": [-0.0063, 0.0008, -0.013, -0.0004]}})
    run = run_scenario(s, tmp_path / "run", engine="direct", progress=False, report=False,
                       recording=MemoryRecording())
    assert run["status"] == "failed" and "trajectory refused" in run["error"], run["error"]
    got = run["metrics"]
    want = metrics_dict(analyse_bag(tmp_path / "run", namespace=run["namespace"], machine_name=run["machine"]),
                        run["published"])
    assert got.pop("bag") == "memory" and want.pop("bag").startswith(str(tmp_path / "run" / "bag"))
    assert got == want


def test_the_pose_solved_beside_the_loop_is_recorded_as_the_loop_solves_it(tmp_path, monkeypatch):
    """Recorded and not read by the controller (sensor-space control), the Gough's DKM
    pose is solved by the bag's writer process (direct_beside): the same messages and
    summaries as a run whose loop solves it (the bag written in the run's process)."""
    s = load_scenario("archi_demo", {"duration_s": 0.4})
    runs = {}
    for fork in (True, False):
        monkeypatch.setattr(direct_recording, "may_fork", lambda fork=fork: fork)
        runs[fork] = run_scenario(s, tmp_path / str(fork), engine="direct", progress=False, report=False)
        assert runs[fork]["status"] == "completed", runs[fork]["error"]
    for topic in (topics.METROLOGY_POSE, topics.METROLOGY_STRUTS, topics.DIAGNOSTICS, topics.DRIVES_COMMAND):
        beside, alone = ([bytes(raw) for _, _, raw in recorded_bytes(tmp_path / str(fork) / "bag", s.namespace,
                                                                     (topic,))] for fork in (True, False))
        assert beside == alone and (beside or topic == topics.DIAGNOSTICS), (topic, len(beside), len(alone))
    sensor = runs[True]["summaries"]["gough_sensor"]
    assert sensor == runs[False]["summaries"]["gough_sensor"] and sensor["dkm_run"], sensor
    assert sensor["solved"] == sensor["published"]["metrology/pose"] == round(0.4 / s.dt_s) + 1, sensor
    assert runs[True]["summaries"]["recorder"]["recorded"] == runs[False]["summaries"]["recorder"]["recorded"]
    assert runs[True]["lost"] == {t: 0 for t in runs[True]["published"]}, runs[True]["lost"]
