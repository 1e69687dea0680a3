"""The panel's web side (pkm_operator.panel_app on a real uvicorn server, no ROS): the
page is served; snapshots are pushed at the configured rate; a page without the token
is view only while the E-stop (WebSocket or its own HTTP route) still gets through;
what an action publishes reaches the node's publish function; the E-stop's own server
answers while the main server's loop is stuck. As an adversary: a page of another
origin, a DNS-rebinding host name, settings beyond the page's ranges and hostile JSON
are refused with nothing published."""

import json
import socket
import threading
import time
import urllib.error
import urllib.request

import pytest
import uvicorn
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from pkm_operator.panel import Panel, PanelModel
from pkm_operator.panel_app import AHEAD, create_app, create_estop_app, served_hosts
from pkm_kinematics import load_machine


def serve(app) -> tuple[str, uvicorn.Server, threading.Thread]:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(16)
    srv = uvicorn.Server(uvicorn.Config(app, log_level="warning", ws="websockets-sansio"))
    thread = threading.Thread(target=srv.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while not srv.started and time.monotonic() < deadline:
        time.sleep(0.02)
    return f"http://127.0.0.1:{sock.getsockname()[1]}/", srv, thread


@pytest.fixture
def server():
    """A panel app with token 'secret-token' on a free port; yields (url, published)."""
    published = []
    panel = Panel(PanelModel(load_machine("archi")))
    url, srv, thread = serve(create_app(panel, published.extend, token="secret-token", rate_hz=25.0))
    yield url, published
    srv.should_exit = True
    thread.join(10)


def result_of(ws, action) -> dict:
    ws.send(action if isinstance(action, str) else json.dumps(action))
    while True:
        message = json.loads(ws.recv(timeout=5))
        if message["type"] == "result":
            return message


def test_the_page_and_the_snapshots_at_their_rate(server):
    url, _ = server
    with urllib.request.urlopen(url, timeout=5) as response:
        assert "E-STOP" in response.read().decode()
    with connect(url.replace("http", "ws") + "ws") as ws:
        hello = json.loads(ws.recv(timeout=5))
        assert hello["type"] == "hello" and hello["machine"]["axes"] == ["x", "y", "theta"]
        start, count = time.monotonic(), 0
        while time.monotonic() - start < 2.0:
            count += json.loads(ws.recv(timeout=5))["type"] == "snapshot"
            ws.send(json.dumps({"type": "heartbeat", "seen": count}))     # drawn
    assert 40 <= count <= 55, count                # 25 per second, paced from one clock


def test_a_page_that_draws_nothing_is_sent_only_a_few_snapshots_ahead(server):
    url, _ = server
    with connect(url.replace("http", "ws") + "ws") as ws:
        assert json.loads(ws.recv(timeout=5))["type"] == "hello"
        count = 0
        with pytest.raises(TimeoutError):
            for _ in range(4 * AHEAD):              # 25/s would never leave the socket silent 0.5 s
                count += json.loads(ws.recv(timeout=0.5))["type"] == "snapshot"
        assert count == AHEAD
        ws.send(json.dumps({"type": "heartbeat", "seen": 3}))
        more = [json.loads(ws.recv(timeout=5))["type"] for _ in range(3)]
        assert more == ["snapshot"] * 3
        with pytest.raises(TimeoutError):
            ws.recv(timeout=0.5)


def test_without_the_token_a_page_is_view_only_but_can_stop_the_machine(server):
    url, published = server
    with connect(url.replace("http", "ws") + "ws") as ws:
        assert json.loads(ws.recv(timeout=5))["authorized"] is False
        refused = result_of(ws, {"type": "feed", "percent": 50})
        assert not refused["ok"] and "not authorized" in refused["message"] and published == []
        assert result_of(ws, {"type": "estop"})["ok"]
    assert published == [("estop", True)]
    request = urllib.request.Request(url + "api/estop", method="POST")
    with urllib.request.urlopen(request, timeout=5) as response:
        assert json.load(response)["ok"]
    assert published == [("estop", True), ("estop", True)]


def test_with_the_token_a_page_controls(server):
    url, published = server
    with connect(url.replace("http", "ws") + "ws?token=secret-token") as ws:
        assert json.loads(ws.recv(timeout=5))["authorized"] is True
        assert result_of(ws, {"type": "feed", "percent": 50})["ok"]
        bad = result_of(ws, {"type": "feed", "percent": 500})
        assert not bad["ok"] and "percent must be a number in [0, 100]" in bad["message"]
        assert "action: not JSON" in result_of(ws, "not json")["message"]
    assert published == [("controller/feed_override", 0.5)]
    with connect(url.replace("http", "ws") + "ws?token=wrong") as ws:
        assert json.loads(ws.recv(timeout=5))["authorized"] is False


class StuckPanel(Panel):
    """A panel whose snapshot blocks its caller (the main server's loop) when told to."""

    stuck = threading.Event()

    def snapshot(self):
        if self.stuck.is_set():
            time.sleep(3.0)
        return super().snapshot()


def test_the_estop_server_answers_while_the_main_loop_is_stuck():
    published = []
    panel = StuckPanel(PanelModel(load_machine("archi")))
    estop_url, estop_srv, estop_thread = serve(create_estop_app(panel, published.extend))
    url, srv, thread = serve(create_app(panel, published.extend, "secret-token", estop_url=estop_url + "estop"))
    try:
        with connect(url.replace("http", "ws") + "ws") as ws:
            assert json.loads(ws.recv(timeout=5))["estop_url"] == estop_url + "estop"
            panel.stuck.set()                       # the next snapshot blocks the main loop
            time.sleep(0.2)
            with pytest.raises(OSError):            # the main server's own route does not answer
                urllib.request.urlopen(urllib.request.Request(url + "api/estop", method="POST"), timeout=1)
            start = time.monotonic()
            with urllib.request.urlopen(urllib.request.Request(estop_url + "estop", method="POST"),
                                        timeout=5) as response:
                assert json.load(response)["ok"]
            assert time.monotonic() - start < 1.0
            assert ("estop", True) in published and panel.estop_latched
            panel.stuck.clear()
    finally:
        panel.stuck.clear()
        for s, t in ((srv, thread), (estop_srv, estop_thread)):
            s.should_exit = True
            t.join(10)


def test_control_always_needs_a_token():
    panel = Panel(PanelModel(load_machine("archi")))
    for token in (None, "", "short"):
        with pytest.raises(ValueError, match="token: the panel needs one"):
            create_app(panel, print, token)


def test_a_page_of_another_origin_is_refused_the_socket(server):
    """A page the operator's browser opens elsewhere may open a WebSocket to 127.0.0.1:
    its Origin is not the panel's, and the handshake is refused (with the token too)."""
    url, published = server
    port = url.split(":")[2].rstrip("/")
    for origin in ("http://evil.example", f"http://evil.example:{port}", "null", f"https://127.0.0.1:{port}0"):
        with pytest.raises(InvalidStatus) as refused:
            connect(url.replace("http", "ws") + "ws?token=secret-token", origin=origin)
        assert refused.value.response.status_code == 403, origin
    # the panel's own page (same origin), by either loopback name
    for name in ("127.0.0.1", "localhost"):
        with connect(f"ws://{name}:{port}/ws?token=secret-token", origin=f"http://{name}:{port}") as ws:
            assert json.loads(ws.recv(timeout=5))["authorized"] is True
            assert result_of(ws, {"type": "feed", "percent": 20})["ok"]
    assert published == [("controller/feed_override", 0.2)] * 2
    # a state-changing request from another origin is refused too; the E-stop is not
    request = urllib.request.Request(url + "api/snapshot", method="POST", headers={"Origin": "http://evil.example"})
    with pytest.raises(urllib.error.HTTPError) as refused:
        urllib.request.urlopen(request, timeout=5)
    assert refused.value.code == 403
    request = urllib.request.Request(url + "api/estop", method="POST", headers={"Origin": "http://evil.example"})
    with urllib.request.urlopen(request, timeout=5) as response:
        assert json.load(response)["ok"]
    assert published[-1] == ("estop", True)


def test_a_rebinding_host_name_is_refused_everything(server):
    """DNS rebinding: evil.example resolves to 127.0.0.1, so its page is same-origin
    with itself; the Host header gives it away: the page, the snapshot and the socket
    are refused."""
    url, published = server
    port = int(url.split(":")[2].rstrip("/"))
    for path in ("", "api/snapshot", "api/machine", "static/panel.js"):
        request = urllib.request.Request(url + path, headers={"Host": f"evil.example:{port}"})
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(request, timeout=5)
        assert refused.value.code == 400 and b"Host" in refused.value.read(), path
    sock = socket.create_connection(("127.0.0.1", port))
    with pytest.raises(InvalidStatus) as refused:
        connect(f"ws://evil.example:{port}/ws?token=secret-token", sock=sock, origin=f"http://evil.example:{port}")
    assert refused.value.response.status_code == 403 and published == []


def test_settings_beyond_the_pages_ranges_are_refused_on_the_server(server):
    """The page offers prestress in [-2000, 2000] N; a hand-made message asked 1e9 N
    (then computed torque moved the tool 13.5 mm): refused naming the range."""
    url, published = server
    with connect(url.replace("http", "ws") + "ws?token=secret-token") as ws:
        json.loads(ws.recv(timeout=5))
        for changes, words in (({"prestress_n": 1e9}, "prestress_n must be a number in [-2000, 2000]"),
                               ({"bandwidth_hz": 0.0}, "bandwidth_hz must be a number in [0.5, 100]"),
                               ({"damping_ratio": True}, "damping_ratio must be a number"),
                               ({"strategy": "rogue"}, "strategy must be one of"),
                               ({"force_limit_n": 1e9}, "'force_limit_n' is not a runtime setting")):
            answer = result_of(ws, {"type": "settings", "changes": changes})
            assert not answer["ok"] and words in answer["message"], (changes, answer)
    assert published == []


def test_hostile_json_is_answered_and_the_socket_stays(server):
    """An array, a 200,000-deep document, not JSON, a type that is no string: each a
    refusal (they ended the socket with a traceback); the page goes on controlling."""
    url, published = server
    with connect(url.replace("http", "ws") + "ws?token=secret-token") as ws:
        json.loads(ws.recv(timeout=5))
        for text, words in (("[1, 2]", "got a JSON list"), ("[" * 200_000 + "]" * 200_000, "nested too deep"),
                            ("not json", "not JSON"), ("null", "got a JSON NoneType"),
                            ('{"type": 5}', "expected a JSON object with a 'type'"),
                            ('{"type": "jog", "axis": {"x": 1}, "step": [1]}', "jog: axis must be one of"),
                            ('{"type": "feed", "percent": NaN}', "percent must be a number in [0, 100]")):
            answer = result_of(ws, text)
            assert not answer["ok"] and words in answer["message"], (text[:40], answer)
        assert result_of(ws, {"type": "feed", "percent": 10})["ok"]
    assert published == [("controller/feed_override", 0.1)]


def test_the_names_a_panel_serves():
    assert served_hosts("127.0.0.1") == {"127.0.0.1", "localhost", "::1"}
    beyond = served_hosts("0.0.0.0", ["panel.shop.example"])
    assert {"localhost", "panel.shop.example", socket.gethostname().lower()} <= beyond
    assert "0.0.0.0" not in beyond and "evil.example" not in beyond
