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

Who may do what (the panel is safe to leave open in a browser that visits other sites):

- Control needs the panel's token, always, on localhost too (as Jupyter): ``?token=``
  on the socket's URL or an ``X-Panel-Token`` header; ``pkm-panel`` prints it in the
  panel's URL and the page keeps it (sessionStorage). Without it a page is view only.
- The ``Host`` of every request must be a name the panel serves (``served_hosts``):
  a DNS-rebinding page (evil.example resolving to 127.0.0.1) gets 400 for everything.
- A browser's WebSocket is not bound by the same-origin policy, so the socket checks
  its ``Origin``: a page of another origin is refused the handshake (403). A client
  without an Origin is no browser (a script); it still needs the token to act. The
  same check guards every request that is not a GET, but for the E-stop.
- The E-stop needs neither: anyone who sees the machine may stop it.
- An action is a JSON object of at most ``MAX_MESSAGE_BYTES``; anything else (an array,
  a document nested too deep, not JSON) is answered with a refusal, never a traceback,
  and the socket stays open. Its values are checked by ``panel.Panel.handle``.

What this does not protect against: a process of the operator's own user (it can read
the token from the terminal or the panel's log, as it can signal the graph), and
traffic on the network when the panel is served beyond localhost without TLS.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
import logging
import socket
from pathlib import Path
from urllib.parse import urlsplit

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect, WebSocketDisconnected

from pkm_kinematics.errors import FieldError

LOG = logging.getLogger("pkm-panel")
STATIC = Path(__file__).with_name("panel_static")
AHEAD = 8          # snapshots a page may have in flight, not yet drawn (module doc)
MAX_MESSAGE_BYTES = 4 * 1024 * 1024       # an action: a program (panel.PROGRAM_MAX_BYTES) and its escapes
OPEN_ROUTES = ("/api/estop",)             # non-GET requests any origin may make


def served_hosts(bind_host: str, extra=()) -> frozenset:
    """The names a page may use to reach a panel bound to ``bind_host`` (its ``Host``
    header, without the port): the loopback names for a loopback address; the address
    itself, the machine's host names and addresses when bound beyond it; and ``extra``
    (``pkm-panel --allow-host``: a name of a reverse proxy or a DNS alias)."""
    names = {"localhost", "127.0.0.1", "::1"}
    host = bind_host.strip("[]").lower()
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        address = None
    if address is None or not address.is_loopback:
        names.add(host)
        for name in (socket.gethostname(), socket.getfqdn()):
            names.add(name.lower())
            try:
                names.update(a.lower() for a in socket.gethostbyname_ex(name)[2])
            except OSError:
                pass
    names.discard("0.0.0.0")
    names.discard("::")
    return frozenset(names | {n.strip("[]").lower() for n in extra})


def host_name(value: str) -> str:
    """The name of a ``Host`` header (``name:port``, ``[v6]:port``), lower case; "" for
    one that is no plain host and port (a user part, a path, a bad bracket)."""
    if not value or any(c in value for c in "@/#?\\ "):
        return ""
    try:
        return urlsplit(f"//{value}").hostname or ""
    except ValueError:
        return ""


class SameOriginGuard:
    """ASGI middleware: the ``Host`` of every request is one of ``hosts``; the
    ``Origin`` (when a browser sends one) of a WebSocket or of a request that is not a
    GET is the panel's own, ``http(s)://`` + its Host (module doc). Refused: 400 for a
    foreign Host, 403 for a foreign Origin (a socket is closed before it is accepted)."""

    def __init__(self, app, hosts, open_paths=OPEN_ROUTES, on_refused=None):
        self.app, self.hosts, self.open_paths, self.on_refused = app, frozenset(hosts), open_paths, on_refused

    def refusal(self, scope) -> str | None:
        """Why ``scope`` is refused (None when it is not)."""
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", ())}
        host = headers.get("host", "")
        if host_name(host) not in self.hosts:
            return f"Host {host!r} is not a name this panel serves"
        origin = headers.get("origin")
        checked = scope["type"] == "websocket" or (scope.get("method") not in ("GET", "HEAD")
                                                   and scope.get("path") not in self.open_paths)
        if checked and origin is not None and origin.lower() not in (f"http://{host}".lower(),
                                                                     f"https://{host}".lower()):
            return f"Origin {origin!r} is not this panel's"
        return None

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        why = self.refusal(scope)
        if why is None:
            return await self.app(scope, receive, send)
        if self.on_refused is not None:
            client = scope.get("client")
            self.on_refused(f"{client[0]}:{client[1]}" if client else "?", why)
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})     # before accept: HTTP 403
            return
        status = 400 if why.startswith("Host") else 403
        await PlainTextResponse(f"refused: {why}", status_code=status)(scope, receive, send)


def parse_action(text: str):
    """A page's message -> (action dict, None) or (None, why it is not one)."""
    if len(text) > MAX_MESSAGE_BYTES:
        return None, f"action: at most {MAX_MESSAGE_BYTES} bytes, got {len(text)}"
    try:
        action = json.loads(text)
    except RecursionError:
        return None, "action: JSON nested too deep"
    except ValueError as exc:
        return None, f"action: not JSON ({exc})"
    if not isinstance(action, dict):
        return None, f"action: expected a JSON object with a 'type', got a JSON {type(action).__name__}"
    return action, None


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


def create_app(panel, publish, token: str, rate_hz: float = 25.0, on_restart=None,
               estop_url: str = "", hosts=served_hosts("127.0.0.1")):
    """The app for ``panel`` (panel.Panel); ``publish``: [(topic, payload)] -> None (the
    node's); ``token``: what control needs (module doc); ``on_restart``: called (in a
    thread) when a reset restarts the graph; ``estop_url``: the E-stop server's
    (create_estop_app), given to the pages; ``hosts``: the names it serves
    (served_hosts). An ASGI app: the Starlette app behind a SameOriginGuard."""
    if not 1.0 <= rate_hz <= 100.0:
        raise FieldError("rate_hz", f"must be in [1, 100] Hz, got {rate_hz}")
    if not isinstance(token, str) or len(token) < 8:
        raise FieldError("token", "the panel needs one of at least 8 characters (control is never open)")

    def authorized(given: str | None) -> bool:
        return given is not None and hmac.compare_digest(given.encode(), token.encode())

    async def execute(action, client: str, allowed: bool) -> dict:
        try:
            result = panel.handle(action, client, allowed)
        except Exception as exc:                   # a defect: refused (nothing published) and logged, the socket stays
            LOG.exception("panel action %r from %s", action.get("type"), client)
            result = panel.malformed(client, f"{action.get('type')}: internal error ({type(exc).__name__}), "
                                             f"nothing sent; see the panel's log")
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

    async def websocket(ws: WebSocket):
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
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    break
                text = message.get("text")
                action, why = parse_action(text) if text is not None else (None, "action: expected a text frame")
                if action is None:
                    await ws.send_json({"type": "result", "action": None, "ok": False,
                                        "message": panel.malformed(client, why).message})
                    continue
                if action.get("type") == "heartbeat" and isinstance(action.get("seen"), int):
                    seen[0] = max(seen[0], action["seen"])
                reply = await execute(action, client, allowed)
                if action.get("type") != "heartbeat":
                    await ws.send_json(reply)
        except (WebSocketDisconnect, WebSocketDisconnected):     # closed by the client; or closed while the
            pass                                                 # sender wrote, then read again (starlette's second kind)
        finally:
            sender.cancel()
            panel.disconnected(client)

    app = Starlette(routes=[Route("/", page), Route("/api/machine", machine), Route("/api/snapshot", snapshot),
                            Route("/api/estop", estop, methods=["POST"]), WebSocketRoute("/ws", websocket),
                            Mount("/static", StaticFiles(directory=STATIC), name="static")])
    return SameOriginGuard(app, hosts, on_refused=panel.refused_request)
