"""The operator panel's web side: a Starlette (ASGI) app served by uvicorn.

``/`` the page (``panel_static/``); ``/ws`` a WebSocket per page: the server pushes a
``snapshot`` (panel.Panel.snapshot) ``rate_hz`` times a second and answers each
action with a ``result``. A page acknowledges what it has drawn: its heartbeat
(``{"type": "heartbeat", "seen": N}``, N snapshots of this connection) lets the server
run at most ``AHEAD`` snapshots ahead, so a page slower than ``rate_hz`` is sent fewer
snapshots, never a growing backlog (which also delayed the socket's keepalive pongs
until the server closed it); ``POST /api/estop`` the E-stop on its own route; ``GET
/api/snapshot`` and ``/api/machine`` the same data as JSON.

The E-stop also has a server of its own (``create_estop_app``: one route, served by a
second uvicorn in its own thread and event loop, on another port): the page sends it
three ways, so it reaches the machine even when the panel's main loop is stuck.

Control needs the panel's token when one is set (``pkm-panel`` sets one whenever it is
bound to anything but the loopback interface): ``?token=`` on the socket's URL or an
``X-Panel-Token`` header; without it a page is view only. The E-stop needs no token:
anyone who sees the machine may stop it.
"""

from __future__ import annotations

import asyncio
import hmac
import json
from pathlib import Path

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect, WebSocketDisconnected

STATIC = Path(__file__).with_name("panel_static")
AHEAD = 8          # snapshots a page may have in flight, not yet drawn (module doc)


def create_estop_app(panel, publish) -> Starlette:
    """``POST /estop``: publish the E-stop first, then tell the panel (which logs it).
    A page on the main server posts here cross-origin (``no-cors``: the request goes,
    its answer is not read)."""
    async def estop(request: Request):
        publish([("estop", True)])
        client = f"estop server {request.client.host}:{request.client.port}" if request.client else "estop server"
        result = panel.handle({"type": "estop"}, client, True)
        return JSONResponse({"type": "result", "action": "estop", "ok": result.ok, "message": result.message})

    return Starlette(routes=[Route("/estop", estop, methods=["POST"])])


def create_app(panel, publish, token: str | None = None, rate_hz: float = 25.0, on_restart=None,
               estop_url: str = "") -> Starlette:
    """The app for ``panel`` (panel.Panel); ``publish``: [(topic, payload)] -> None (the
    node's); ``on_restart``: called (in a thread) when a reset restarts the graph;
    ``estop_url``: the E-stop server's (create_estop_app), given to the pages."""
    if not 1.0 <= rate_hz <= 100.0:
        raise ValueError(f"rate_hz: must be in [1, 100] Hz, got {rate_hz}")

    def authorized(given: str | None) -> bool:
        return token is None or (given is not None and hmac.compare_digest(given, token))

    async def execute(action, client: str, allowed: bool) -> dict:
        result = panel.handle(action, client, allowed)
        if result.publish:
            publish(result.publish)
        if result.restart and on_restart is not None:
            await asyncio.to_thread(on_restart)
        return {"type": "result", "action": action.get("type") if isinstance(action, dict) else None,
                "ok": result.ok, "message": result.message}

    async def page(request: Request):
        return FileResponse(STATIC / "index.html")

    async def machine(request: Request):
        return JSONResponse(panel.model.describe())

    async def snapshot(request: Request):
        return JSONResponse(panel.snapshot())

    async def estop(request: Request):
        client = f"http {request.client.host}:{request.client.port}" if request.client else "http"
        return JSONResponse(await execute({"type": "estop"}, client, True))

    async def socket(ws: WebSocket):
        await ws.accept()
        client = f"{ws.client.host}:{ws.client.port}" if ws.client else "page"
        allowed = authorized(ws.query_params.get("token") or ws.headers.get("x-panel-token"))
        await ws.send_json({"type": "hello", "machine": panel.model.describe(), "authorized": allowed,
                            "rate_hz": rate_hz, "estop_url": estop_url})
        panel.heartbeat(client)

        seen = [0]                                 # the page's last acknowledgement

        async def push():
            period = 1.0 / rate_hz
            loop = asyncio.get_running_loop()
            next_t, sent = loop.time(), 0
            while True:
                if sent - seen[0] < AHEAD:
                    await ws.send_text(json.dumps({"type": "snapshot", **panel.snapshot()}))
                    sent += 1
                next_t += period
                await asyncio.sleep(max(0.0, next_t - loop.time()))

        sender = asyncio.create_task(push())
        try:
            while True:
                text = await ws.receive_text()
                try:
                    action = json.loads(text)
                except ValueError:
                    action = None
                if isinstance(action, dict) and action.get("type") == "heartbeat" and isinstance(action.get("seen"), int):
                    seen[0] = max(seen[0], action["seen"])
                reply = await execute(action, client, allowed)
                if action is None or action.get("type") != "heartbeat":
                    await ws.send_json(reply)
        except (WebSocketDisconnect, WebSocketDisconnected):     # closed by the client; or closed while the
            pass                                                 # sender wrote, then read again (starlette's second kind)
        finally:
            sender.cancel()
            panel.disconnected(client)

    return Starlette(routes=[Route("/", page), Route("/api/machine", machine), Route("/api/snapshot", snapshot),
                             Route("/api/estop", estop, methods=["POST"]), WebSocketRoute("/ws", socket),
                             Mount("/static", StaticFiles(directory=STATIC), name="static")])
