"""Run reports (pkm_runs.report) on synthetic recordings: no ROS graph.

The bags are written with rosbags (rosbag2 version 9, MCAP, CDR, ros2msg schemas) like
the recorder writes them, with known tracking errors, drive forces and internal forces,
so the metrics can be checked against exact values. The report streams the bag in
blocks: the same metrics must come out whatever the block size."""

import json
import math

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pkm_runs import report
from pkm_runs.report_data import RunReader
from pkm_runs.report_metrics import RunAnalysis, metrics_dict
from pkm_runs.report_plots import MinMaxDecimator, StrideDecimator, Unwrapper
from pkm_kinematics import load_machine
from pkm_kinematics.distribution import min_two_norm, null_direction

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
NS = "/pkm"
N = 400                       # steps
DT_NS = 1_000_000             # 1 ms sim step
WALL_STEP_NS = 2_000_000      # 2 ms wall per step: 500 Hz, half real time
WALL0 = 1_700_000_000 * 10**9
ERR_X = 10e-6                 # constant x error (m)
SPIKE_K, SPIKE_Y = 150, 50e-6  # extra y error at one step
YAW_ERR, YAW_SPIKE_K, YAW_SPIKE = 20e-6, 250, -100e-6
PEAK_CMD_K, PEAK_CMD = 123, -1500.0


# ------------------------------------------------------------ message helpers
def header(ns):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                    frame_id="world")


def joint_state(ns, names, position=(), velocity=(), effort=()):
    return T["sensor_msgs/msg/JointState"](
        header=header(ns), name=list(names), position=np.asarray(position, dtype=float),
        velocity=np.asarray(velocity, dtype=float), effort=np.asarray(effort, dtype=float))


def pose_stamped(ns, x, y, z, yaw=0.0):
    return T["geometry_msgs/msg/PoseStamped"](header=header(ns), pose=T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw))))


def diagnostics(ns, name, level, message, values):
    status = T["diagnostic_msgs/msg/DiagnosticStatus"](
        level=level, name=name, message=message, hardware_id="",
        values=[T["diagnostic_msgs/msg/KeyValue"](key=k, value=str(v)) for k, v in values.items()])
    return T["diagnostic_msgs/msg/DiagnosticArray"](header=header(ns), status=[status])


def clock(ns):
    return T["rosgraph_msgs/msg/Clock"](clock=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9))


def trajectory(points):
    v3, q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    twist = T["geometry_msgs/msg/Twist"](linear=v3(x=0.0, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0))
    pts = [T["trajectory_msgs/msg/MultiDOFJointTrajectoryPoint"](
        transforms=[T["geometry_msgs/msg/Transform"](translation=v3(x=x, y=y, z=0.0),
                                                     rotation=q(x=0.0, y=0.0, z=math.sin(th / 2), w=math.cos(th / 2)))],
        velocities=[twist], accelerations=[twist],
        time_from_start=T["builtin_interfaces/msg/Duration"](sec=int(t), nanosec=int(round((t % 1) * 1e9))))
        for t, (x, y, th) in points]
    return T["trajectory_msgs/msg/MultiDOFJointTrajectory"](header=header(0), joint_names=["tool"], points=pts)


TYPES = {"/clock": "rosgraph_msgs/msg/Clock",
         f"{NS}/drives/state": "sensor_msgs/msg/JointState",
         f"{NS}/drives/command": "sensor_msgs/msg/JointState",
         f"{NS}/platform/true_pose": "geometry_msgs/msg/PoseStamped",
         f"{NS}/controller/reference": "geometry_msgs/msg/PoseStamped",
         f"{NS}/controller/status": "diagnostic_msgs/msg/DiagnosticArray",
         f"{NS}/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
         f"{NS}/trajectory": "trajectory_msgs/msg/MultiDOFJointTrajectory",
         f"{NS}/load": "geometry_msgs/msg/WrenchStamped",
         f"{NS}/estop": "std_msgs/msg/Bool"}


def write_bag(path, records):
    """records: (topic, log_ns, message or CDR bytes); written in log-time order."""
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, log_ns, msg in sorted(records, key=lambda r: r[1]):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, TYPES[topic], typestore=TS)
            writer.write(conns[topic], log_ns, msg if isinstance(msg, bytes) else TS.serialize_cdr(msg, TYPES[topic]))


def count(records):
    out = {}
    for topic, _, _ in records:
        out[topic] = out.get(topic, 0) + 1
    return out


# ------------------------------------------------------------ synthetic runs
def archi_run(tmp_path, tripped=False, extra=(), name="archi_run"):
    """An ARCHI-like run with known errors and forces (``extra``: more (topic, log_ns,
    message) records). Returns (run_dir, expected)."""
    cfg = load_machine("archi")
    model, names = cfg.model, cfg.model.leg_names
    s = np.arange(N) / N
    ref = np.column_stack([1.0 + 0.05 * np.sin(2 * np.pi * s), -0.4 + 0.03 * (1 - np.cos(2 * np.pi * s)),
                           0.785 + 0.3 * s])
    true = ref + [ERR_X, 0.0, YAW_ERR]
    true[SPIKE_K, 1] += SPIKE_Y
    true[YAW_SPIKE_K, 2] = ref[YAW_SPIKE_K, 2] + YAW_SPIKE
    internal = 40.0 + 5.0 * np.sin(2 * np.pi * s)                # known internal-force norm (N)
    applied = np.empty((N, 4))
    for k in range(N):
        jac = model.jacobian(true[k])
        wrench = [200.0 * np.sin(2 * np.pi * s[k]), 100.0 * np.cos(2 * np.pi * s[k]), 10.0]
        applied[k] = min_two_norm(jac, wrench) + internal[k] * null_direction(jac)
    commanded = applied.copy()
    commanded[PEAK_CMD_K, 1] = PEAK_CMD
    q = model.inverse_kinematics_batch(true)[0]

    recs = []
    # the step-0 state, pose, command and reference repeated before the run starts
    for d in (3, 2, 1):
        recs.append((f"{NS}/drives/state", WALL0 - d * 10**8, joint_state(0, names, q[0], [0] * 4, applied[0])))
        recs.append((f"{NS}/platform/true_pose", WALL0 - d * 10**8 + 1000,
                     pose_stamped(0, *true[0, :2], 0.0, true[0, 2])))
    recs.append((f"{NS}/drives/command", WALL0 - 10**8 + 3000, joint_state(0, names, effort=[0.0] * 4)))
    recs.append((f"{NS}/controller/reference", WALL0 - 10**8 + 4000, pose_stamped(0, 0.0, 0.0, 0.0)))
    for k in range(N):
        ns, wall = k * DT_NS, WALL0 + k * WALL_STEP_NS
        recs += [("/clock", wall, clock(ns)),
                 (f"{NS}/drives/state", wall + 50_000, joint_state(ns, names, q[k], [0.0] * 4, applied[k])),
                 (f"{NS}/platform/true_pose", wall + 100_000, pose_stamped(ns, *true[k, :2], 0.0, true[k, 2])),
                 (f"{NS}/drives/command", wall + 300_000, joint_state(ns, names, effort=commanded[k])),
                 (f"{NS}/controller/reference", wall + 350_000, pose_stamped(ns, *ref[k, :2], 0.0, ref[k, 2]))]
        if k % 100 == 99:
            level, message = (2, "stopped: following error") if tripped and k == N - 1 else (0, "tracking")
            recs.append((f"{NS}/controller/status", wall + 400_000, diagnostics(
                ns, "controller", level, message, {"mode": "tracking", "tracking_error_m": repr(1e-5),
                                                   "cycles": k + 1, "faults": "none"})))
    for k, misses in ((0, 0), (200, 2), (N - 1, 3)):
        wall = WALL0 + k * WALL_STEP_NS + 450_000
        recs.append((f"{NS}/diagnostics", wall, diagnostics(k * DT_NS, "sim_hw", 0, "running",
                                                            {"step": k, "deadline_misses": misses,
                                                             "internal_force_norm_n": 40.0})))
        recs.append((f"{NS}/diagnostics", wall + 1, diagnostics(k * DT_NS, "gough_sensor", 0, "ok", {"refused": 0})))
    recs.append((f"{NS}/trajectory", WALL0 - 5 * 10**8, trajectory([(0.0, ref[0]), (0.2, ref[200]), (0.4, ref[-1])])))
    v3 = T["geometry_msgs/msg/Vector3"]
    recs.append((f"{NS}/load", WALL0 + 10, T["geometry_msgs/msg/WrenchStamped"](
        header=header(0), wrench=T["geometry_msgs/msg/Wrench"](force=v3(x=10.0, y=0.0, z=0.0),
                                                              torque=v3(x=0.0, y=0.0, z=1.0)))))
    if tripped:
        recs.append((f"{NS}/estop", WALL0 + N * WALL_STEP_NS, T["std_msgs/msg/Bool"](data=True)))

    recs += list(extra)
    run_dir = tmp_path / name
    run_dir.mkdir()
    write_bag(run_dir / "bag", recs)
    recorded = count(recs)
    published = stamp_count(recs)     # nodes count one publication per stamp, not the repeats
    published[f"{NS}/drives/state"] += 5
    published["metrology/pose"] = 10                  # published, none recorded (relative name)
    (run_dir / "run.json").write_text(json.dumps({"scenario": "synthetic", "machine": "archi", "namespace": NS,
                                                  "published": published}))
    trans = np.full(N, ERR_X)
    trans[SPIKE_K] = math.hypot(ERR_X, SPIKE_Y)
    yaw = np.full(N, YAW_ERR)
    yaw[YAW_SPIKE_K] = abs(YAW_SPIKE)
    return run_dir, dict(ref=ref, true=true, applied=applied, commanded=commanded, internal=internal,
                         trans=trans, yaw=yaw, recorded=recorded, published=published)


@pytest.fixture(scope="module")
def archi(tmp_path_factory):
    return archi_run(tmp_path_factory.mktemp("archi"))


def test_load_run_dedupes_step_zero(archi):
    run_dir, exp = archi
    run = report.load_run(run_dir)
    assert run.namespace == NS
    assert run.state.recorded == N + 3 and len(run.state.stamp_ns) == N and run.state.duplicates == 3
    assert np.array_equal(run.state.stamp_ns, np.arange(N) * DT_NS)
    # the last copy of a stamp is kept: step 0's log time is the run's, not the warm-up's
    assert run.state.log_ns[0] == WALL0 + 50_000
    assert run.command.duplicates == 1 and run.reference.duplicates == 1 and run.true_pose.duplicates == 3
    assert run.state.names == ["q1", "q2", "q3", "q4"]
    np.testing.assert_allclose(run.state.effort, exp["applied"], rtol=0, atol=0)
    np.testing.assert_allclose(run.true_pose.yaw, exp["true"][:, 2], atol=1e-12)
    assert run.counts[f"{NS}/drives/state"] == N + 3
    assert len(run.clock_ns) == N
    assert [r.name for r in run.statuses["sim_hw"]] == ["sim_hw"] * 3
    assert run.trajectory_position.shape == (3, 3)
    np.testing.assert_allclose(run.trajectory_time_s, [0.0, 0.2, 0.4], rtol=0, atol=1e-15)
    points = exp["ref"][[0, 200, -1]]
    np.testing.assert_allclose(run.trajectory_position[:, :2], points[:, :2], rtol=0, atol=1e-15)
    np.testing.assert_allclose(run.trajectory_yaw, points[:, 2], rtol=0, atol=1e-15)
    np.testing.assert_allclose(run.load_force[0], [10.0, 0.0, 0.0])


def stamp_count(recs) -> dict:
    """Messages per topic whose header stamp differs from the previous one of the topic."""
    out, last = {}, {}
    for topic, log_ns, msg in sorted(recs, key=lambda r: r[1]):
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec) if hasattr(msg, "header") else object()
        if stamp != last.get(topic):
            out[topic] = out.get(topic, 0) + 1
        last[topic] = stamp
    return out


def test_archi_metrics(archi):
    run_dir, exp = archi
    m = report.metrics(report.load_run(run_dir), "archi", exp["published"])
    json.dumps(m, allow_nan=False)                          # JSON-serialisable, no NaN
    assert m["machine"] == "archi" and m["kind"] == "planar" and m["steps"] == N
    assert m["duration_s"] == pytest.approx((N - 1) * 1e-3)
    assert m["duplicates_dropped"][f"{NS}/drives/state"] == 3

    te = m["tracking_error"]
    trans = exp["trans"]                                    # the warm-up (zero) reference of step 0 is dropped
    assert te["samples"] == N
    assert te["rms_m"] == pytest.approx(math.sqrt(((N - 1) * ERR_X ** 2 + trans[SPIKE_K] ** 2) / N), rel=1e-6)
    assert te["max_m"] == pytest.approx(math.hypot(ERR_X, SPIKE_Y), rel=1e-6)
    assert te["max_time_s"] == pytest.approx(SPIKE_K * 1e-3)
    assert te["rms_axis_m"][0] == pytest.approx(ERR_X, rel=1e-6)
    assert te["yaw_rms_rad"] == pytest.approx(math.sqrt(((N - 1) * YAW_ERR ** 2 + YAW_SPIKE ** 2) / N), rel=1e-6)
    assert te["yaw_max_rad"] == pytest.approx(abs(YAW_SPIKE), rel=1e-6)
    assert te["yaw_max_time_s"] == pytest.approx(YAW_SPIKE_K * 1e-3)

    df = m["drive_force"]
    assert df["peak_commanded_n"] == pytest.approx(abs(PEAK_CMD))
    assert df["peak_applied_n"] == pytest.approx(np.max(np.abs(exp["applied"])))
    assert df["peak_commanded_per_drive_n"]["q2"] == pytest.approx(abs(PEAK_CMD))

    fi = m["internal_force"]
    assert fi["redundancy"] == 1 and fi["samples"] == N and fi["unavailable_steps"] == 0
    assert fi["pose_source"] == "true_pose"
    assert fi["max_n"] == pytest.approx(45.0, rel=1e-9)
    assert fi["rms_n"] == pytest.approx(math.sqrt(np.mean(exp["internal"] ** 2)), rel=1e-9)

    assert m["deadline_misses"] == 3
    assert m["timing"]["loop_rate_hz"] == pytest.approx(1e9 / WALL_STEP_NS)
    assert m["timing"]["sim_wall_ratio"] == pytest.approx(DT_NS / WALL_STEP_NS)

    msgs = m["messages"]
    assert msgs["recorded"][f"{NS}/drives/state"] == N + 3
    assert msgs["lost"][f"{NS}/drives/state"] == 5
    assert msgs["lost"][f"{NS}/metrology/pose"] == 10
    assert msgs["lost"][f"{NS}/drives/command"] == 0
    assert msgs["lost_total"] == 15

    c = m["controller"]
    assert not c["tripped"] and c["trip_reason"] is None and not c["estop"]
    assert m["trip_cause"] == "none" and m["trip_reason"] == "" and m["trip_time_s"] is None
    assert c["final_status"]["level"] == 0 and c["final_status"]["message"] == "tracking"
    assert c["final_status"]["values"]["cycles"] == N and c["final_status"]["values"]["tracking_error_m"] == 1e-5


def test_internal_force_matches_distribution(archi):
    """The per-step series is the null-space norm of the applied forces."""
    run_dir, exp = archi
    run = report.load_run(run_dir)
    fi = report.internal_forces(run, load_machine("archi"))
    np.testing.assert_allclose(fi["norm"], exp["internal"], rtol=1e-9)


def test_machine_inferred_from_drive_names(archi):
    run_dir, exp = archi
    m = report.metrics(report.load_run(run_dir))
    assert m["machine"] == "archi" and m["machine_source"] == "drive names"
    assert m["messages"]["lost"] is None
    assert m["internal_force"]["max_n"] == pytest.approx(45.0)


def test_tripped_run(tmp_path):
    run_dir, _ = archi_run(tmp_path, tripped=True)
    m = report.metrics(report.load_run(run_dir), "archi")
    assert m["controller"]["tripped"] and m["controller"]["estop"]
    assert m["controller"]["trip_reason"] == "controller status level 2: stopped: following error"
    assert m["controller"]["final_status"]["level"] == 2
    # a status of level 2 that names no cause (recorded before causes were published)
    assert m["trip_cause"] == "unknown" and m["trip_reason"] == "stopped: following error"
    assert m["trip_source"] == "controller" and m["trip_time_s"] == pytest.approx((N - 1) * 1e-3)


def test_a_trajectory_point_without_its_transform_is_read_as_nan(tmp_path):
    # the last trajectory is the run's; cdr's decoder refuses this one, rosbags' objects read it
    late = trajectory([(0.0, (1.0, -0.4, 0.0)), (0.5, (1.1, -0.3, 0.2))])
    late.points[0].transforms = []
    run_dir, _ = archi_run(tmp_path, extra=[(f"{NS}/trajectory", WALL0 - 10**8, late)])
    run = report.load_run(run_dir)
    assert np.isnan(run.trajectory_position[0]).all() and np.isnan(run.trajectory_yaw[0])
    np.testing.assert_allclose(run.trajectory_position[1], [1.1, -0.3, 0.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(run.trajectory_yaw[1], 0.2, rtol=0, atol=1e-15)
    np.testing.assert_allclose(run.trajectory_time_s, [0.0, 0.5])


def test_write_report_and_plots(archi, capsys):
    run_dir, exp = archi
    out = run_dir / "report"
    assert report.main([str(run_dir)]) == 0
    text = capsys.readouterr().out
    assert "tracking error" in text and "internal force" in text and "deadline misses" in text
    data = json.loads((out / "metrics.json").read_text())
    assert data["scenario"] == "synthetic" and data["machine"] == "archi"
    assert data["messages"]["lost"][f"{NS}/drives/state"] == 5
    assert set(data["plots"]) == {"path.png", "tracking_error.png", "drive_forces.png", "internal_force.png"}
    for name in data["plots"]:
        blob = (out / name).read_bytes()
        assert blob[:8] == b"\x89PNG\r\n\x1a\n" and len(blob) > 5000


def test_out_dir_and_plot_function(archi, tmp_path):
    run_dir, _ = archi
    files = report.plot(report.load_run(run_dir / "bag"), tmp_path / "figs", "archi")
    assert len(files) == 4 and all(f.stat().st_size > 5000 for f in files)


def test_main_without_bag(tmp_path, capsys):
    assert report.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no rosbag2 recording" in err and str(tmp_path) in err


# ------------------------------------------------------------ translational
def test_mom3_no_redundancy(tmp_path):
    cfg = load_machine("mom3")
    names = cfg.model.leg_names
    s = np.arange(N) / N
    ref = np.column_stack([0.02 * np.sin(2 * np.pi * s), 0.02 * (np.cos(2 * np.pi * s) - 1), 0.882 + 0.01 * s])
    true = ref + [ERR_X, 0.0, 0.0]
    rng = np.random.default_rng(3)
    forces = rng.uniform(-300.0, 300.0, (N, 3))
    recs = []
    for k in range(N):
        ns, wall = k * DT_NS, WALL0 + k * WALL_STEP_NS
        recs += [(f"{NS}/drives/state", wall, joint_state(ns, names, [0.0] * 3, [0.0] * 3, forces[k])),
                 (f"{NS}/platform/true_pose", wall + 1, pose_stamped(ns, *true[k])),
                 (f"{NS}/drives/command", wall + 2, joint_state(ns, names, effort=forces[k])),
                 (f"{NS}/controller/reference", wall + 3, pose_stamped(ns, *ref[k]))]
    run_dir = tmp_path / "mom3_run"
    run_dir.mkdir()
    write_bag(run_dir / "bag", recs)              # no run.json: machine from the drive names

    m = report.write_report(run_dir)
    assert m["machine"] == "mom3" and m["kind"] == "translational"
    assert m["internal_force"]["max_n"] == 0.0 and m["internal_force"]["rms_n"] == 0.0
    assert m["internal_force"]["redundancy"] == 0
    assert m["internal_force"]["max_commanded_n"] == 0.0
    te = m["tracking_error"]
    assert te["rms_m"] == pytest.approx(ERR_X, rel=1e-6) and te["max_m"] == pytest.approx(ERR_X, rel=1e-6)
    assert "yaw_rms_rad" not in te
    assert len(te["rms_axis_m"]) == 3
    assert m["drive_force"]["peak_applied_n"] == pytest.approx(np.max(np.abs(forces)))
    assert m["deadline_misses"] is None and m["controller"]["final_status"] is None
    assert not m["controller"]["tripped"]
    assert m["messages"]["lost"] is None and m["messages"]["recorded"][f"{NS}/drives/state"] == N
    assert set(m["plots"]) == {"path.png", "tracking_error.png", "drive_forces.png", "internal_force.png"}
    assert (run_dir / "report" / "metrics.json").is_file()


def test_decimation_keeps_spikes_and_bounds_the_points():
    """Fed in pieces of any size, the min/max decimation holds at most ~limit points of a
    long curve, in time order, and keeps a one-sample spike and dip; a short curve whole."""
    y = np.zeros(100_000)
    y[54_321], y[12_345] = 7.0, -3.0
    y[80_000:80_010] = np.nan
    decimator = MinMaxDecimator(2000)
    for start, stop in zip(range(0, 100_000, 777), list(range(777, 100_000, 777)) + [100_000]):
        decimator.add(np.arange(start, stop), y[start:stop])
    t, v = decimator.curve()
    assert len(t) <= 2000 + decimator.size and np.all(np.diff(t) > 0)
    assert 54_321 in t and 12_345 in t and np.nanmax(v) == 7.0 and np.nanmin(v) == -3.0
    short = MinMaxDecimator(2000)
    short.add(np.arange(1500), np.sin(np.arange(1500.0)))
    assert np.array_equal(short.curve()[0], np.arange(1500))


def test_stride_decimation_and_piecewise_unwrap():
    stride = StrideDecimator(2, limit=1000)
    rows = np.column_stack([np.arange(10_007.0), -np.arange(10_007.0)])
    for start in range(0, len(rows), 333):
        stride.add(rows[start:start + 333])
    kept = stride.rows()
    assert len(kept) <= 1001 and kept[0, 0] == 0 and kept[-1, 0] == 10_006 and np.all(np.diff(kept[:, 0]) > 0)
    angle = np.angle(np.exp(1j * np.linspace(0.0, 40.0, 5000)))       # wraps many times
    unwrapper = Unwrapper()
    pieces = np.concatenate([unwrapper.add(angle[k:k + 97]) for k in range(0, len(angle), 97)])
    np.testing.assert_allclose(pieces, np.unwrap(angle), rtol=0, atol=1e-9)


def _same(a, b, path=""):
    """Equal metrics, floats to 1e-12 relative (a RMS sums blocks in another order)."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{i}]")
    elif isinstance(a, float):
        assert b == pytest.approx(a, rel=1e-12), path
    else:
        assert a == b, path


def test_streaming_in_small_blocks_gives_the_same_metrics(archi):
    """Blocks of 7 stamps closed 3 steps behind the newest: the stamps are deduplicated
    and joined across block boundaries as in one block of the whole run."""
    run_dir, exp = archi
    whole = report.metrics(report.load_run(run_dir), "archi", exp["published"])
    with RunReader(run_dir, block_rows=7, lookback_ns=3 * DT_NS) as reader:
        analysis = RunAnalysis(reader.info, "archi")
        sizes = []
        for block in reader.blocks():
            sizes.append(len(block))
            analysis.add(block)
    assert max(sizes) <= 7 and len(sizes) >= N // 7
    _same(whole, metrics_dict(analysis.finish(), exp["published"]))
    assert whole["late_dropped"] == {}


def test_a_stamp_older_than_the_look_back_is_dropped_and_counted(tmp_path):
    """A message of a stamp already handed out (older than the look-back) is not kept:
    counted as dropped, the earlier copy of the stamp stays."""
    late = joint_state(5 * DT_NS, ["q1", "q2", "q3", "q4"], [0.0] * 4, [0.0] * 4, [9999.0] * 4)
    run_dir, exp = archi_run(tmp_path, extra=[(f"{NS}/drives/state", WALL0 + N * WALL_STEP_NS, late)])
    with RunReader(run_dir, block_rows=16, lookback_ns=20 * DT_NS) as reader:
        analysis = RunAnalysis(reader.info, "archi")
        for block in reader.blocks():
            analysis.add(block)
    m = metrics_dict(analysis.finish())
    assert m["late_dropped"] == {f"{NS}/drives/state": 1}
    assert m["duplicates_dropped"][f"{NS}/drives/state"] == 3 + 1
    assert m["drive_force"]["peak_applied_n"] == pytest.approx(np.max(np.abs(exp["applied"])))


def test_mixed_layouts_are_decoded_message_by_message(tmp_path):
    """Blocks whose messages do not share one layout (the plant's status word in
    frame_id from a step on, drives in another order, an array of another length, big-
    endian CDR) are decoded message by message, in the stream's drive order."""
    names = ["q1", "q2", "q3", "q4"]
    steps = 300
    rng = np.random.default_rng(7)
    q, f = rng.normal(size=(steps, 4)), rng.normal(scale=100.0, size=(steps, 4))
    recs = []
    for k in range(steps):
        frame = "safe_stop:plant_safe_stop" if k >= 150 else ""
        order = names[::-1] if k % 37 == 5 else names
        pick = [names.index(n) for n in order]
        effort = f[k, pick][:3] if k == 77 else f[k, pick]
        msg = T["sensor_msgs/msg/JointState"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=k * DT_NS),
                                            frame_id=frame),
            name=order, position=q[k, pick], velocity=np.zeros(4), effort=effort)
        pose = pose_stamped(k * DT_NS, 1.0, -0.4, 0.0, 0.785)
        recs += [(f"{NS}/drives/state", WALL0 + k * WALL_STEP_NS, msg),
                 (f"{NS}/platform/true_pose", WALL0 + k * WALL_STEP_NS + 1,
                  bytes(TS.serialize_cdr(pose, TYPES[f"{NS}/platform/true_pose"], little_endian=k % 2 == 0)))]
    run_dir = tmp_path / "mixed"
    run_dir.mkdir()
    write_bag(run_dir / "bag", recs)
    run = report.load_run(run_dir)
    assert run.state.names == names and len(run.state.stamp_ns) == steps
    np.testing.assert_array_equal(run.state.position, q)
    expected = f.copy()
    expected[77] = np.nan
    np.testing.assert_array_equal(run.state.effort, expected)
    np.testing.assert_allclose(run.true_pose.yaw, 0.785, rtol=0, atol=1e-12)
    assert np.all(run.true_pose.position == [1.0, -0.4, 0.0])


# ------------------------------------------------------------ the cause of a stop
def _status(topic_suffix, k, log_ns, name, level, message, cause=None):
    values = {"mode": "stopped" if level == 2 else "tracking"}
    if cause is not None:
        values["cause"] = cause
    return (f"{NS}/{topic_suffix}", log_ns, diagnostics(k * DT_NS, name, level, message, values))


def test_the_first_stop_by_stamp_gives_the_cause(tmp_path, capsys):
    """The plant stops at step 200 on its own (plant_safe_stop); the controller, seeing
    drives that no longer follow, stops at step 210 (drive_failure) and its status
    reaches the bag first: the report names the plant's stop, the one that started it."""
    wall = WALL0 + 210 * WALL_STEP_NS
    stops = [_status("controller/status", 210, wall + 500_000, "controller", 2, "stopped: drive q2 failed",
                     "drive_failure"),
             _status("diagnostics", 200, wall + 900_000, "sim_hw", 2, "stopped: end stop q3", "plant_safe_stop"),
             _status("diagnostics", 230, wall + 20 * WALL_STEP_NS, "sim_hw", 2, "stopped: end stop q3",
                     "plant_safe_stop"),
             (f"{NS}/estop", wall + 600_000, T["std_msgs/msg/Bool"](data=True))]
    run_dir, _ = archi_run(tmp_path, extra=stops)
    assert report.main([str(run_dir)]) == 0
    text = capsys.readouterr().out
    m = json.loads((run_dir / "report" / "metrics.json").read_text())
    assert m["trip_cause"] == "plant_safe_stop" and m["trip_reason"] == "stopped: end stop q3"
    assert m["trip_source"] == "sim_hw" and m["trip_time_s"] == pytest.approx(0.2)
    assert m["sim_hw"]["stopped"] and m["controller"]["tripped"] and m["controller"]["estop"]
    assert m["controller"]["trip_reason"] == "controller status level 2: stopped: drive q2 failed"
    assert "plant_safe_stop at 0.200 s (sim_hw: stopped: end stop q3)" in text


def test_a_controller_stop_before_the_plants_estop(tmp_path):
    """The controller trips (following_error) and latches the estop; the plant brakes on
    it a step later (cause estop): the cause is the controller's."""
    stops = [_status("controller/status", 300, WALL0 + 300 * WALL_STEP_NS + 400_000, "controller", 2,
                     "stopped: following error 12 mm", "following_error"),
             _status("diagnostics", 301, WALL0 + 301 * WALL_STEP_NS + 1000, "sim_hw", 2, "stopped: estop", "estop")]
    run_dir, _ = archi_run(tmp_path, extra=stops)
    m = report.write_report(run_dir)
    assert (m["trip_cause"], m["trip_reason"], m["trip_source"]) == \
        ("following_error", "stopped: following error 12 mm", "controller")
    assert "following_error at 0.300 s" in report.summary(m)


def test_an_estop_without_an_error_status(tmp_path):
    run_dir, _ = archi_run(tmp_path, extra=[(f"{NS}/estop", WALL0 + 10 * WALL_STEP_NS, T["std_msgs/msg/Bool"](
        data=True))])
    m = report.write_report(run_dir)
    assert (m["trip_cause"], m["trip_reason"], m["trip_source"]) == ("estop", "estop true", "estop")
    assert m["controller"]["tripped"] and m["controller"]["trip_reason"] == "estop true"


def test_null_space_part_matches_distribution():
    """The vectorised projection is distribution.internal_force_rows step by step; a
    singular J or a NaN gives NaN instead of raising."""
    from pkm_kinematics.distribution import internal_force_rows

    rng = np.random.default_rng(5)
    jac = rng.normal(size=(50, 4, 3))
    forces = rng.normal(scale=100.0, size=(50, 4))
    jac[7, :, 2] = jac[7, :, 0]                   # rank 2
    forces[9, 1] = np.nan
    got = report.null_space_part(jac, forces)
    for k in range(50):
        if k in (7, 9):
            assert np.isnan(got[k]).all()
        else:
            np.testing.assert_allclose(got[k], internal_force_rows(jac[k].tolist(), forces[k].tolist()),
                                       rtol=1e-9, atol=1e-9)


def test_rpy_of_quaternions_is_the_models_roll_pitch_yaw():
    from scipy.spatial.transform import Rotation

    from pkm_runs.report_data import rpy_of
    from pkm_kinematics.rotations import rpy_from_rotation
    rotations = Rotation.random(50, random_state=3)
    expected = [rpy_from_rotation(m) for m in rotations.as_matrix()]
    np.testing.assert_allclose(rpy_of(rotations.as_quat()), expected, atol=1e-12)


def test_a_non_planar_tool_reports_the_angle_of_its_rotation_error():
    from scipy.spatial.transform import Rotation

    from pkm_runs.report_metrics import tracking_error_rows
    true, ref = Rotation.random(20, random_state=5), Rotation.random(20, random_state=6)
    e = tracking_error_rows(np.zeros((20, 3)), true.as_quat(), np.zeros((20, 3)), ref.as_quat(), planar=False)
    np.testing.assert_allclose(e["rotation"], (true * ref.inv()).magnitude(), atol=1e-7)
    assert "rotation" not in tracking_error_rows(np.zeros((20, 3)), true.as_quat(), np.zeros((20, 3)),
                                                 ref.as_quat(), planar=True)
