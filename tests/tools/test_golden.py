"""tools/golden.py's own rules (the comparison itself runs with `make golden`)."""

import importlib.util
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("golden", ROOT / "tools" / "golden.py")
golden = importlib.util.module_from_spec(spec)
spec.loader.exec_module(golden)


def _msg(stamp_ns, effort):
    stamp = SimpleNamespace(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp), effort=effort)


def test_what_measures_the_host_is_left_out_and_numbers_keep_nine_digits():
    flat = golden._flat({"timing": {"wall_s": 3.0, "sim_s": 1.927}, "controller": {"compute_us_p50": 50.0},
                         "messages": {"recorded": {"/clock": 4958}, "published": {"/clock": 1928}},
                         "tracking_error": {"rms_m": 8.142819281234e-05}, "run_dir": "/tmp/x", "bag": "/tmp/x/bag"})
    assert flat == {"timing.sim_s": 1.927, "messages.published./clock": 1928, "tracking_error.rms_m": 8.14281928e-05}


def test_a_stamp_repeated_while_the_graph_connects_is_digested_once():
    once = golden._digest([_msg(0, [1.0]), _msg(1_000_000, [2.0])], lambda m: m.effort)
    repeated = golden._digest([_msg(0, [1.0]), _msg(0, [1.0]), _msg(1_000_000, [2.0])], lambda m: m.effort)
    changed = golden._digest([_msg(0, [1.0]), _msg(1_000_000, [2.0000000000000004])], lambda m: m.effort)
    assert once == repeated and once["count"] == 2 and changed["sha256"] != once["sha256"]


def test_differences_name_the_scenario_and_the_field():
    want = {"scenarios": {"a": {"commands": {"count": 2, "sha256": "x"}, "metrics": {"rms_m": 1.0}}}, "analyze": {}}
    got = {"scenarios": {"a": {"commands": {"count": 2, "sha256": "y"}, "metrics": {"rms_m": 1.0}},
                         "b": {"commands": {}}}, "analyze": {}}
    assert golden.differences(want, got) == ["scenarios a commands.sha256: 'x' -> 'y'",
                                             "scenarios b: not in the golden outputs"]
