"""pkm-panel with a hexapod: the panel starts ``panel_hexapod`` (hexapod8, eight struts,
6 DOF, in real time) and a WebSocket client, as a page would, jogs the yaw c in rad:
accepted, planned by the trajectory node and reached by the machine (the true pose the
plant publishes); a 0.2 rad jog is refused by name and nothing moves; the E-stop
stops the machine and the controller says why. The panel's hexapod core (axes, rad
bounds, drawing) is tested in test_panel.py; this is the same against a running graph."""

import json
import subprocess
import sys
import urllib.request

import pytest
import yaml

from pkm_kinematics.config import config_dir

from panel_helpers import (base, realtime_profile_permitted, snapshot, ws_url, wait_for, wait_for_a_holding_graph,
                           without_sync_counter)     # tests/operator/panel_helpers.py

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not realtime_profile_permitted(),
                                 reason="the hexapod's 250 Hz loop beside the panel needs the realtime profile "
                                        "(root, or CAP_SYS_NICE and CAP_IPC_LOCK): without it, start-up stalls "
                                        "tripped its drives' sync monitor on this 2-core machine")]


def pose_c(url: str) -> float:
    return (snapshot(url).get("pose") or [float("nan")] * 6)[5]


def test_the_panel_jogs_a_hexapod_in_rad_and_its_estop_stops_it(tmp_path, realtime_loop_alone):
    from websockets.sync.client import connect
    scenario = yaml.safe_load((config_dir() / "scenarios" / "panel_hexapod.yaml").read_text())
    scenario["realtime_profile"] = True
    scenario["duration_s"], scenario["timeout_s"] = 120.0, 180.0      # an upper bound: the test ends it
    scenario = without_sync_counter(scenario)
    scenario_path = tmp_path / "panel_hexapod.yaml"
    scenario_path.write_text(yaml.safe_dump(scenario))
    url_file = tmp_path / "url"
    panel = subprocess.Popen([sys.executable, "-m", "pkm_operator.panel_main", "--start", str(scenario_path),
                              "--runs", str(tmp_path / "runs"), "--port", "0", "--url-file", str(url_file)],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        url = wait_for("the panel's URL", lambda: url_file.exists() and url_file.read_text(), timeout_s=120)
        wait_for_a_holding_graph(url)
        with urllib.request.urlopen(base(url) + "api/machine", timeout=5) as response:
            machine = json.load(response)
        assert machine["axes"] == ["x", "y", "z", "a", "b", "c"] and machine["angular"] == ["a", "b", "c"]
        state = snapshot(url)
        assert len(state["drawing"]["legs"]) == 8 and len(state["drawing"]["struts"]) == 6
        home = state["reference"]
        with connect(ws_url(url)) as ws:
            ws.recv()                                                             # hello

            def ask(message: dict) -> dict:
                ws.send(json.dumps(message))
                while True:
                    answer = json.loads(ws.recv())
                    if answer["type"] == "result":
                        return answer

            def alive() -> None:                                                  # the page's heartbeat
                ws.send(json.dumps({"type": "heartbeat"}))

            answer = ask({"type": "jog", "axis": "c", "step": 0.02})
            assert answer["ok"] and answer["message"] == "jog c +0.02 rad", answer
            wait_for("the yaw at +0.02 rad", lambda: alive() or abs(pose_c(url) - home[5] - 0.02) < 1e-4,
                     timeout_s=30)
            refused = ask({"type": "jog", "axis": "a", "step": 0.2})
            assert not refused["ok"] and "0 < |step| <= 0.1 rad" in refused["message"], refused
            reference = snapshot(url)["reference"]
            assert reference[:5] == pytest.approx(home[:5], abs=1e-12)            # nothing else moved
            assert reference[5] == pytest.approx(home[5] + 0.02, abs=1e-12)
            assert ask({"type": "estop"})["ok"]
        stopped = wait_for("the controller stopped", lambda: (lambda s: s if "estop" in s["controller"]["message"]
                                                              else None)(snapshot(url)), timeout_s=20)
        assert stopped["controller"]["values"].get("cause") == "estop", stopped["controller"]
    finally:
        panel.terminate()
        output, _ = panel.communicate(timeout=120)
        print(output[-4000:])
    assert panel.returncode == 0, output[-4000:]
