"""What the panel's end-to-end tests share: a snapshot of the panel, waiting for a
condition, and whether the realtime profile is allowed here."""

import json
import time
import urllib.request
from urllib.parse import parse_qs, urlsplit


def base(url: str) -> str:
    """The panel's root, without the token pkm-panel's URL carries: http://host:port/."""
    parts = urlsplit(url)
    return f"{parts.scheme}://{parts.netloc}/"


def ws_url(url: str) -> str:
    """The panel's socket with the token of ``url`` (pkm-panel's printed URL): control."""
    token = parse_qs(urlsplit(url).query)["token"][0]
    return base(url).replace("http", "ws", 1) + f"ws?token={token}"


def snapshot(url: str) -> dict:
    with urllib.request.urlopen(base(url) + "api/snapshot", timeout=5) as response:
        return json.load(response)


def wait_for(what: str, predicate, timeout_s: float = 30.0, period_s: float = 0.1):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(period_s)
    raise AssertionError(f"timed out waiting for {what}")


def realtime_profile_permitted() -> bool:
    from pkm_bringup.rt_profile import RealtimeProfileRefused, check_permitted
    try:
        check_permitted()
    except RealtimeProfileRefused:
        return False
    return True


def wait_for_a_holding_graph(url: str) -> None:
    """The panel's graph holding still, and every action's reader (the planner, the
    controller) discovered: the panel would refuse an action before (panel.RECEIVERS)."""
    wait_for("the graph holding", lambda: snapshot(url)["controller"]["values"].get("mode") == "holding",
             timeout_s=90)
    wait_for("the planner and the controller discovered", lambda: not snapshot(url)["unreached"], timeout_s=30)


def without_sync_counter(scenario: dict) -> dict:
    """``scenario`` with the drives' sync error counter off. In a slow phase of this VM
    a start-up stall (21-46 cycles held in the first 0.5 s, in two suites) braked the
    plant before a test could act; the panel's actions are what these tests check
    (the counter: tests/sim_hw/test_sync_monitor.py)."""
    return {**scenario, "plant": {**scenario.get("plant", {}), "sync_error_limit": 0}}
