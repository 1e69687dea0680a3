"""The panel's web side (pkm_bringup.panel_app on a real uvicorn server, no ROS): the
page is served; snapshots are pushed at the configured rate; with a token set, a page
without it is view only while the E-stop (WebSocket or its own HTTP route) still gets
through; what an action publishes reaches the node's publish function; the E-stop's
own server answers while the main server's loop is stuck."""

import json
import socket
import threading
import time
import urllib.request

import pytest
import uvicorn
from websockets.sync.client import connect

from pkm_bringup.panel import Panel, PanelModel
from pkm_bringup.panel_app import AHEAD, create_app, create_estop_app
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
    """A panel app with token 'secret' on a free port; yields (url, published)."""
    published = []
    panel = Panel(PanelModel(load_machine("archi")))
    url, srv, thread = serve(create_app(panel, published.extend, token="secret", rate_hz=25.0))
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
    with connect(url.replace("http", "ws") + "ws?token=secret") as ws:
        assert json.loads(ws.recv(timeout=5))["authorized"] is True
        assert result_of(ws, {"type": "feed", "percent": 50})["ok"]
        bad = result_of(ws, {"type": "feed", "percent": 500})
        assert not bad["ok"] and "percent must be a number in [0, 100]" in bad["message"]
        assert "expected a JSON object" in result_of(ws, "not json")["message"]
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
    url, srv, thread = serve(create_app(panel, published.extend, estop_url=estop_url + "estop"))
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
