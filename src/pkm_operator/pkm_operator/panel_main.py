"""``pkm-panel``: the web operator panel of a running graph.

    pkm-panel --start panel_archi [--rt-profile]   # starts the graph (pkm-run) and serves the panel
    pkm-panel --machine archi --credential runs/<run>/credential.key   # joins a running graph

then open http://127.0.0.1:8080/ . The panel joins the graph of this shell's
``ROS_DOMAIN_ID`` in ``--namespace`` (with ``--start``: the scenario's namespace, and a
domain claimed for the panel and its graph when the shell sets none). It is bound to
127.0.0.1 by default. Control always needs a token (``--token``, or one is made): it is
in the URL printed at start, which the page keeps; a page of another origin or a
request by another host name (``--allow-host`` adds one) is refused; the E-stop stays
open to every page (panel_app's doc says what this protects against). Every action is
logged, accepted or refused (stderr, and ``--log`` as JSON lines). The panel's
commands carry the run's credential (pkm_common.credential): with ``--start`` the
panel makes a new key for each run it starts (in a private temporary directory,
removed at exit); to join a run, ``--credential`` names the run's key file.
"""

from __future__ import annotations

import argparse
import json
import logging
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import rclpy
import uvicorn
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

from pkm_bringup.processes import die_with_parent, use_ros_environment
from pkm_bringup.rt_profile import RealtimeProfileRefused, check_permitted
from pkm_bringup.scenario import ScenarioError, load_scenario
from pkm_common.credential import RunKey
from pkm_common.poses import MACHINE_KINDS
from pkm_kinematics import load_machine
from pkm_operator.panel import Panel, PanelModel
from pkm_operator.panel_app import MAX_MESSAGE_BYTES, create_app, create_estop_app, served_hosts
from pkm_operator.panel_node import PanelNode

LOG = logging.getLogger("pkm-panel")


class Graph:
    """A graph the panel started: ``pkm-run SCENARIO`` as a child process; a reset
    ends it (SIGTERM: its run is recorded and reported as interrupted) and starts
    another run of the same scenario. The graph dies with the panel, however the panel
    ends (PR_SET_PDEATHSIG, as pkm-run's own nodes): an orphan would hold the machine
    and its domain with nobody to stop it. The signal follows the thread that started
    the graph: the main thread, or a worker of asyncio's default executor (a reset),
    which lives until the panel's event loop closes."""

    def __init__(self, scenario: str, runs: str, rt_profile: bool = False, key_file: Path | None = None,
                 on_key=None):
        self.scenario, self.process = scenario, None
        self.key_file, self.on_key = key_file, on_key
        self.command = [sys.executable, "-m", "pkm_bringup.orchestrator", scenario, "--runs", runs,
                        "--no-progress", *(["--rt-profile"] if rt_profile else []),
                        *(["--credential", str(key_file)] if key_file else [])]
        self.lock = threading.Lock()

    def start(self) -> None:
        """A new run, with a new key (``on_key(key)``: the panel signs with it)."""
        with self.lock:
            if self.key_file is not None:
                key = RunKey.create(self.key_file)
                if self.on_key is not None:
                    self.on_key(key)
            self.process = subprocess.Popen(self.command, preexec_fn=die_with_parent)
            LOG.info("graph started: pkm-run %s (pid %d)", self.scenario, self.process.pid)

    def stop(self, timeout_s: float = 60.0) -> None:
        with self.lock:
            if self.process is not None and self.process.poll() is None:
                self.process.send_signal(signal.SIGTERM)
                try:
                    self.process.wait(timeout_s)
                except subprocess.TimeoutExpired:
                    self.process.kill()
                    self.process.wait()

    def restart(self, between=None) -> None:
        """Stop, call ``between()`` (the old graph is gone; called whatever the stop
        raised: the panel listens again), start."""
        try:
            self.stop()
        finally:
            if between is not None:
                between()
        self.start()


# the machines the panel draws and jogs: every kind the graph runs (a hexapod's six axes,
# its angles jogged in rad)
PANEL_KINDS = MACHINE_KINDS

def listening_socket(host: str, port: int) -> socket.socket:
    """Bound and listening (connections wait in the backlog until uvicorn serves)."""
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    sock.listen(64)
    return sock


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-panel", description=__doc__.split("\n\n")[0])
    parser.add_argument("--start", metavar="SCENARIO", help="start this scenario's graph (pkm-run) and reset it "
                                                             "from the panel (mode: realtime scenarios)")
    parser.add_argument("--rt-profile", action="store_true",
                        help="start the graph with the realtime profile (pkm-run --rt-profile: SCHED_FIFO for the "
                             "loop, ahead of the browser and the panel on the same cores; needs root or "
                             "CAP_SYS_NICE and CAP_IPC_LOCK)")
    parser.add_argument("--runs", default="runs", help="parent of the started runs' directories (default: runs)")
    parser.add_argument("--machine", help="the machine of a running graph (default: the scenario's, or archi)")
    parser.add_argument("--namespace", help="the graph's namespace (default: the scenario's, or /pkm)")
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default: 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8080, help="port (0: any free one; default 8080)")
    parser.add_argument("--estop-port", type=int, default=0,
                        help="port of the E-stop's own server (default 0: any free one; the page is told)")
    parser.add_argument("--token", help="token required for control (default: one is made; printed in the URL)")
    parser.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                        help="a further name pages may reach the panel by (a proxy, a DNS alias); repeatable")
    parser.add_argument("--rate-hz", type=float, default=25.0, help="snapshots per second to each page (1-100)")
    parser.add_argument("--log", help="append every action (JSON lines) to this file")
    parser.add_argument("--url-file", help="write the panel's URL here once it serves (scripts, tests)")
    parser.add_argument("--credential", metavar="FILE",
                        help="the run's key file (RUN_DIR/credential.key) to join a run; with --start one is made")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s pkm-panel: %(message)s")
    for name in ("port", "estop_port"):
        if not 0 <= getattr(args, name) <= 65535:
            parser.error(f"--{name.replace('_', '-')}: must be in [0, 65535], got {getattr(args, name)}")
    if not 1.0 <= args.rate_hz <= 100.0:
        parser.error(f"--rate-hz: must be in [1, 100], got {args.rate_hz}")
    if args.start and args.credential:
        parser.error("--credential joins a running graph; with --start the panel makes each run's key")

    machine, namespace = args.machine or "archi", args.namespace or "/pkm"
    if args.start:
        try:
            s = load_scenario(args.start)
        except ScenarioError as exc:
            print(f"pkm-panel: {exc}", file=sys.stderr)
            return 2
        if s.mode != "realtime":
            print(f"pkm-panel: --start {args.start}: mode must be realtime (a lockstep graph runs as fast as it "
                  f"can and ends), got {s.mode}", file=sys.stderr)
            return 2
        machine, namespace = args.machine or s.machine, args.namespace or s.namespace
        domain = use_ros_environment()["ROS_DOMAIN_ID"]       # the panel's and its graph's (this shell's, or claimed)
        LOG.info("the graph runs in ROS_DOMAIN_ID=%s", domain)
        if args.rt_profile or s.realtime_profile:
            try:
                check_permitted()
            except RealtimeProfileRefused as exc:
                print(f"pkm-panel: {exc}", file=sys.stderr)
                return 2
    token = args.token if args.token is not None else secrets.token_urlsafe(16)
    if len(token) < 8:
        parser.error("--token: at least 8 characters")
    try:
        config = load_machine(machine)
    except ValueError as exc:
        print(f"pkm-panel: --machine: {exc}", file=sys.stderr)
        return 2
    if config.kind not in PANEL_KINDS:
        print(f"pkm-panel: --machine: {config.name} is a {config.kind} machine; the panel draws and jogs "
              f"{' and '.join(PANEL_KINDS)} machines so far", file=sys.stderr)
        return 2
    log_file = open(args.log, "a", encoding="utf-8") if args.log else None   # noqa: SIM115 - until exit

    def log_line(entry: dict) -> None:
        LOG.info("%s %s from %s: %s", "done" if entry["ok"] else "REFUSED", entry["type"], entry["client"],
                 entry["message"])
        if log_file is not None:
            log_file.write(json.dumps(entry) + "\n")
            log_file.flush()

    key, key_dir = None, None
    if args.credential:
        try:
            key = RunKey.read(args.credential)
        except ValueError as exc:
            print(f"pkm-panel: --{exc}".replace("credential_file", "credential"), file=sys.stderr)
            return 2
    elif args.start:                  # each run it starts gets a new key (Graph.start)
        key_dir = Path(tempfile.mkdtemp(prefix="pkm-panel-"))
        key = RunKey.create(key_dir / "credential.key")
    else:
        LOG.warning("no --credential: a run started by pkm-run refuses this panel's commands (give it the run's "
                    "RUN_DIR/credential.key)")
    panel = Panel(PanelModel(config), can_reset=bool(args.start), log=log_line)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = PanelNode(panel, namespace, context=context, key=key)
    graph = Graph(args.start, args.runs, args.rt_profile, key_dir / "credential.key",
                  on_key=lambda k: setattr(node.signer, "key", k)) if args.start else None
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:        # rclpy.try_shutdown at exit ends the spin this way
            pass
    spinner = threading.Thread(target=spin, name="panel-ros", daemon=True)
    spinner.start()
    sock = listening_socket(args.host, args.port)
    estop_sock = listening_socket(args.host, args.estop_port)
    host, port = sock.getsockname()[:2]
    if host in ("0.0.0.0", "::"):        # every interface: a URL by a name the panel serves (served_hosts)
        host = socket.gethostname()
    base = f"http://{host if ':' not in host else f'[{host}]'}"
    url = f"{base}:{port}/?token={token}"
    # the E-stop's own server: a second uvicorn in its own thread and event loop
    estop_server = uvicorn.Server(uvicorn.Config(create_estop_app(panel, node.publish), log_level="warning"))
    threading.Thread(target=estop_server.run, kwargs={"sockets": [estop_sock]}, name="panel-estop",
                     daemon=True).start()
    app = create_app(panel, node.publish, token, args.rate_hz, on_restart=(lambda: graph.restart(panel.restarted)) if graph else None,
                     estop_url=f"{base}:{estop_sock.getsockname()[1]}/estop",
                     hosts=served_hosts(args.host, args.allow_host))
    if graph is not None:
        graph.start()
    print(f"pkm-panel: {machine} in {namespace}: {url}", flush=True)
    if args.url_file:
        Path(args.url_file).write_text(url, encoding="utf-8")
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", ws="websockets-sansio",
                                           ws_max_size=MAX_MESSAGE_BYTES))
    signal.signal(signal.SIGTERM, lambda *_: setattr(server, "should_exit", True))
    try:
        server.run(sockets=[sock])
    finally:
        estop_server.should_exit = True
        if graph is not None:
            graph.stop()
        rclpy.try_shutdown(context=context)      # ends executor.spin
        spinner.join(5.0)
        executor.shutdown()
        node.destroy_node()
        if log_file is not None:
            log_file.close()
        if key_dir is not None:
            shutil.rmtree(key_dir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
