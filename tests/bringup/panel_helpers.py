"""What the panel's end-to-end tests share: a snapshot of the panel, waiting for a
condition, and whether the realtime profile is allowed here."""

import json
import time
import urllib.request


def snapshot(url: str) -> dict:
    with urllib.request.urlopen(url + "api/snapshot", timeout=5) as response:
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
