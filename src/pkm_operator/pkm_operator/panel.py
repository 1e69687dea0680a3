"""The operator panel's core (pure: no rclpy, no web server): what ``pkm-panel`` shows
and what it lets an operator do, every action validated before anything reaches the
graph.

``PanelModel`` is constant per machine (its axes, workspace, drawing). ``Panel`` is
the live side: the node feeds it what the graph publishes (``on_*``, any thread), the
web app asks it for a ``snapshot`` to send to the pages and hands it each action of a
page (``handle``), which returns what to publish, or a refusal that names the field
and the allowed range, with nothing published. Sliding Star §4 (Fig. 12) is the model:
initialise, position, manual / automatic / trajectory, regulator gains, projection
ON/OFF, measured data, 3-axis incremental motion.

Actions (JSON objects from the page, ``type`` first):

=========  ==============================  ===========================================
type       fields                          what is published
=========  ==============================  ===========================================
estop      (none; never needs a token)     ``estop`` true (latched by the controller
                                           and the drives; here until ``reset``)
reset      (none)                          the graph restarted, when the panel started
                                           it (a stopped run stays a finished record)
program    text (G-code), name             nothing: parsed (line and word of an error)
start      (none)                          ``program``: the loaded program, planned
                                           by trajectory_node from the current pose
feed       percent in [0, 100]             ``controller/feed_override`` (0: hold)
jog        axis, step (m or rad)           ``goal``: the current reference moved by
                                           step, inside the workspace, |step| bounded
settings   changes {name: value}           ``controller/settings``, checked by a
                                           controller core first (change_settings)
heartbeat  (none)                          nothing: a jog whose page falls silent for
                                           HEARTBEAT_TIMEOUT_S is held (feed 0)
=========  ==============================  ===========================================

Motion (start, jog) is refused while the controller is not holding still (another
trajectory runs, or it is stopped) or the E-stop is latched: by the panel, by the
graph's ``estop``, by a controller status that says stopped, or by the drives' status
word saying they braked. An action whose reader does
not subscribe yet (``RECEIVERS``: the planner or the controller not discovered, as the
node's ``receivers`` count says) is refused, not published: a message sent before its
reader is matched is lost, and the panel would have said "done".
"""

from __future__ import annotations

import collections
import json
import math
import threading
import time
from dataclasses import dataclass, field

from pkm_common.causes import plant_status
from pkm_common.poses import machine_pose_components, pose_from_components, tool_pose_to_machine
from pkm_controller.config import RUNTIME_SETTINGS, ControllerConfig
from pkm_controller.controller import ControllerCore
from pkm_controller.strategies import REGISTRY as STRATEGIES
from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics.analysis import workspace_box
from pkm_kinematics.distribution import METHODS
from pkm_kinematics.errors import FieldError
from pkm_sim_hw.plant import leg_segments
from pkm_trajectory.program import gcode_segments

HEARTBEAT_TIMEOUT_S = 0.5       # a jog whose page is silent this long is held
JOG_MAX_M = 0.01                # one jog increment at most (Sliding Star: incremental motion)
JOG_MAX_RAD = 0.1
PROGRAM_MAX_BYTES = 1_000_000
# the topic each action publishes on, the node that must read it, and its description
# (another reader does not count: the recorder subscribes to every topic it discovers)
RECEIVERS = {"start": ("program", "trajectory", "the planner (trajectory_node)"),
             "jog": ("goal", "trajectory", "the planner (trajectory_node)"),
             "feed": ("controller/feed_override", "controller", "the controller"),
             "settings": ("controller/settings", "controller", "the controller")}
PLOT_PERIOD_S = 0.02            # tracking error samples kept for the plot, per simulated second
PLOT_POINTS = 500               # 10 s of plot
SETTING_RANGES = {              # the page's inputs; the controller core has the last word
    "bandwidth_hz": (0.5, 100.0), "damping_ratio": (0.1, 10.0), "integral_time_s": (0.0, 10.0),
    "p_norm": (2.0, 64.0), "prestress_n": (-2000.0, 2000.0)}


def check_setting(name, value) -> None:
    """One setting of a page against what the page offers (``PanelModel.describe``):
    the runtime settings only, a strategy or distribution of the lists, a number in
    ``SETTING_RANGES``. The running controller's own rule follows (Panel._settings).
    ValueError naming the field and the allowed values."""
    choices = {"strategy": list(STRATEGIES), "distribution": list(METHODS)}
    if name not in RUNTIME_SETTINGS:
        raise FieldError("settings", f"{_shown(name)} is not a runtime setting; one of {list(RUNTIME_SETTINGS)}")
    if name in choices:
        if value not in choices[name]:
            raise FieldError("settings", f"{name} must be one of {choices[name]}, got {_shown(value)}")
        return
    lo, hi = SETTING_RANGES[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
        raise FieldError("settings", f"{name} must be a number in [{lo:g}, {hi:g}], got {_shown(value)}")


def _shown(value, limit: int = 40) -> str:
    """``repr(value)``, cut to ``limit`` characters (a page may send anything)."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


class PanelModel:
    """What the panel knows of the machine (constant): axes, workspace, drawing."""

    def __init__(self, machine):
        self.machine = machine
        self.model = machine.model
        self.space = self.model.task_space
        self.planar = self.space.translation_axes == 2      # (x, y, theta): its angle is a yaw
        self.kind = machine.kind
        self.axes = self.space.axes
        self.angular = self.axes[self.space.translation_axes:]     # rad: theta, or a hexapod's a, b, c
        self.box = workspace_box(self.model)
        self.home = [float(v) for v in self.model.home]
        self.gough = None
        if machine.metrology is not None:
            self.gough = GoughSensorModel(machine.metrology)

    def describe(self) -> dict:
        """The page's set-up: names, axes and their jog bounds, workspace, settings."""
        return {"machine": self.machine.name, "kind": self.kind, "axes": list(self.axes),
                "drives": list(self.model.leg_names), "workspace": [list(b) for b in self.box],
                "jog_max": {a: (JOG_MAX_RAD if a in self.angular else JOG_MAX_M) for a in self.axes},
                "angular": list(self.angular),
                "strategies": list(STRATEGIES), "distributions": list(METHODS),
                "setting_ranges": SETTING_RANGES, "home": self.home}

    def to_machine(self, position, orientation, reference_theta=None) -> list:
        """A PoseStamped's position and quaternion -> machine coordinates."""
        p, r = pose_from_components(position, orientation)
        return tool_pose_to_machine(self.space, p, r, reference_theta).tolist()

    def drawing(self, pose, struts: bool = True) -> dict:
        """Legs (carriage -> platform joint), the platform outline and (``struts``) the
        Gough struts at the machine pose ``pose`` (world coordinates, metres)."""
        try:
            legs = leg_segments(self.model, pose)
        except ValueError:                    # outside the machine's reach: nothing drawn
            return {"legs": [], "platform": [], "struts": []}
        joints = [b for _, b in legs]
        cx = sum(p[0] for p in joints) / len(joints)
        cy = sum(p[1] for p in joints) / len(joints)
        outline = sorted(joints, key=lambda p: math.atan2(p[1] - cy, p[0] - cx))
        strut_lines = []
        if struts and self.gough is not None:
            position, orientation = machine_pose_components(self.space, pose)
            p, r = pose_from_components(position, orientation)
            strut_lines = self.gough.strut_segments(p, r)
        return {"legs": legs, "platform": outline, "struts": strut_lines}


@dataclass
class Result:
    """The outcome of an action: ``publish`` is [(topic, payload)] for the node."""

    ok: bool
    message: str
    publish: list = field(default_factory=list)
    restart: bool = False


class Panel:
    """The live panel of one graph (thread-safe: the node and the web app share it)."""

    def __init__(self, model: PanelModel, can_reset: bool = False, clock=time.monotonic, log=None):
        self.model, self.can_reset, self.clock, self.log_line = model, can_reset, clock, log
        self.lock = threading.Lock()
        self.state = None                 # (stamp_ns, names, position, velocity, effort, word)
        self.state_clock = None           # clock() at the last state: a graph gone silent is shown
        self.pose = self.reference = None
        self.references: dict[int, list] = {}
        self.poses: dict[int, list] = {}
        self.plot = collections.deque(maxlen=PLOT_POINTS)
        self.last_plot_ns = None
        self.status = (0, "no controller yet", {})
        self.diagnostics: dict[str, tuple] = {}
        self.cia402: dict[str, dict] = {}  # servo drives (drives/cia402): name -> state, statusword, error
        self.events = collections.deque(maxlen=20)
        self.actions = collections.deque(maxlen=20)
        self.estop_latched, self.estop_why = False, ""
        self.program = None               # (name, text, moves)
        self.jog = None                   # {"client", "target", "since"}
        self.heartbeats: dict[str, float] = {}
        self.sent: dict[str, float] = {}  # action kind -> monotonic time published, for its latency
        self.latency_ms: dict[str, float] = {}
        self.counts = collections.Counter()
        self.receivers = None             # (topic, node) -> that node's matched readers (the node's); None: not asked
        self.restarting = False           # a reset until restarted(): the old graph still publishes

    def connect(self, receivers) -> None:
        """``receivers(topic, node)``: how many subscriptions of the node named ``node``
        the panel's publisher of ``topic`` has matched (PanelNode). Without it every
        action is published."""
        self.receivers = receivers

    def _unreached(self, kind: str) -> str | None:
        """Why ``kind`` cannot be sent now (None if it can)."""
        if kind not in RECEIVERS or self.receivers is None:
            return None
        topic, node, who = RECEIVERS[kind]
        if self.receivers(topic, node) > 0:
            return None
        return f"{kind}: not sent: {who} does not read {topic} yet (not discovered, or not matched); try again"

    # ------------------------------------------------------------ from the graph
    def on_state(self, stamp_ns, names, position, velocity, effort, word) -> None:
        with self.lock:
            if self.restarting:           # the ended run's last words (restarted())
                return
            self.state = (stamp_ns, list(names), list(position), list(velocity), list(effort), word)
            self.state_clock = self.clock()
            self.counts["drives/state"] += 1
            status = plant_status(word)
            if not status.stopped:
                return
            if "estop" in self.sent and "estop" not in self.latency_ms:
                self.latency_ms["estop"] = 1e3 * (self.clock() - self.sent["estop"])   # press -> drives braked
            # the drives' own word latches too: the controller's status saying so can be
            # missed (a volatile topic, a panel matched late), the word is on every state
            if not self.estop_latched:
                self.estop_latched, self.estop_why = True, f"the drives braked: {status.cause.value}"

    def on_struts(self) -> None:
        """The Gough sensor publishes (its struts are drawn)."""
        with self.lock:
            if self.restarting:
                return
            self.counts["metrology/struts"] += 1

    def on_true_pose(self, stamp_ns, position, orientation) -> None:
        with self.lock:
            if self.restarting:           # the ended run's last words (restarted())
                return
            ref_theta = self.pose[2] if self.pose is not None and self.model.planar else None
            self.pose = self.model.to_machine(position, orientation, ref_theta)
            self._pair(stamp_ns, pose=self.pose)

    def on_reference(self, stamp_ns, position, orientation) -> None:
        with self.lock:
            if self.restarting:           # the ended run's last words (restarted())
                return
            ref_theta = self.reference[2] if self.reference is not None and self.model.planar else None
            self.reference = self.model.to_machine(position, orientation, ref_theta)
            self._pair(stamp_ns, reference=self.reference)

    def _pair(self, stamp_ns, pose=None, reference=None) -> None:
        """The tracking error x_d(k) - x(k) of the same step k, for the plot."""
        mine, other = (self.poses, self.references) if pose is not None else (self.references, self.poses)
        value = pose if pose is not None else reference
        partner = other.pop(stamp_ns, None)
        if partner is None:
            mine[stamp_ns] = value
            while len(mine) > 64:
                del mine[next(iter(mine))]
            return
        p, r = (value, partner) if pose is not None else (partner, value)
        if self.last_plot_ns is None or not 0 <= stamp_ns - self.last_plot_ns < PLOT_PERIOD_S * 1e9:
            error = math.sqrt(sum((r[i] - p[i]) ** 2 for i in range(self.model.space.translation_axes)))
            self.plot.append((stamp_ns * 1e-9, error * 1e6))
            self.last_plot_ns = stamp_ns

    def on_status(self, name: str, level: int, message: str, values: dict) -> None:
        with self.lock:
            if self.restarting:           # the ended run's last words (restarted())
                return
            if name == "controller":
                self.status = (level, message, values)
                if values.get("mode") == "stopped" and not self.estop_latched:
                    self.estop_latched, self.estop_why = True, f"controller stopped: {message}"
            else:
                self.diagnostics[name] = (level, message)

    def on_drive_states(self, statuses) -> None:
        """drives/cia402: each servo drive's (name, level, CiA 402 state, values) (pkm_drives)."""
        with self.lock:
            if self.restarting:
                return
            self.cia402 = {name: {"level": level, "state": message, "node_id": values.get("node_id"),
                                  "statusword": values.get("statusword", ""), "error": values.get("error", "none"),
                                  "homing": values.get("homing", "")}
                           for name, level, message, values in statuses}

    def on_estop(self, active: bool) -> None:
        with self.lock:
            if self.restarting:           # the ended run's last words (restarted())
                return
            if active and not self.estop_latched:
                self.estop_latched, self.estop_why = True, self.estop_why or "estop from the graph"

    def on_event(self, text: str) -> None:
        """A controller/events record (pkm_controller.operator_actions): the latency of the action."""
        try:
            event = json.loads(text)
        except ValueError:
            return
        with self.lock:
            if self.restarting:
                return
            self.events.append(event)
            kind = event.get("kind")
            # the E-stop's latency runs to the drives braking (on_state), not to the event
            sent = None if kind == "estop" else self.sent.pop(kind, None)
            if sent is not None:
                self.latency_ms[kind] = 1e3 * (self.clock() - sent)   # published -> applied by the controller

    # ------------------------------------------------------------------ the page
    def snapshot(self) -> dict:
        # graph queries: outside the lock
        unreached = [kind for kind in RECEIVERS if self._unreached(kind) is not None]
        with self.lock:
            level, message, values = self.status
            out = {"machine": self.model.machine.name, "wall_s": time.time(),
                   "controller": {"level": level, "message": message, "values": values},
                   "diagnostics": {k: list(v) for k, v in self.diagnostics.items()},
                   "cia402": {k: dict(v) for k, v in self.cia402.items()},
                   "estop": {"latched": self.estop_latched, "why": self.estop_why, "can_reset": self.can_reset},
                   "events": list(self.events)[-5:], "actions": list(self.actions)[-8:],
                   "program": None if self.program is None else {"name": self.program[0], "moves": self.program[2]},
                   "jog": None if self.jog is None else {"target": self.jog["target"]},
                   "latency_ms": dict(self.latency_ms), "counts": dict(self.counts),
                   "pose": self.pose, "reference": self.reference, "plot": list(self.plot),
                   "silent_s": None if self.state_clock is None else self.clock() - self.state_clock,
                   "unreached": unreached}
            if self.state is not None:
                stamp, names, position, velocity, effort, word = self.state
                out.update(t_s=stamp * 1e-9, drives={"names": names, "position": position, "effort": effort,
                                                     "status": word})
            pose, measuring = self.pose, self.counts["metrology/struts"] > 0
        if pose is not None:
            out["drawing"] = self.model.drawing(pose, struts=measuring)
        return out

    def heartbeat(self, client: str) -> None:
        with self.lock:
            self.heartbeats[client] = self.clock()

    def disconnected(self, client: str) -> None:
        with self.lock:
            self.heartbeats.pop(client, None)

    def watchdog(self) -> Result | None:
        """Hold a jog whose page went silent (heartbeat) or closed; end a finished one."""
        with self.lock:
            jog = self.jog
            if jog is None:
                return None
            if self.reference is not None and max(abs(a - b) for a, b in zip(self.reference, jog["target"])) < 1e-9:
                self.jog = None                    # arrived
                return None
            last = self.heartbeats.get(jog["client"])
            if last is not None and self.clock() - last <= HEARTBEAT_TIMEOUT_S:
                return None
            self.jog = None
        why = "closed" if last is None else f"silent for more than {HEARTBEAT_TIMEOUT_S:g} s"
        return self._done(f"watchdog ({jog['client']})", "feed", True,
                          f"jog held: its panel connection {why} (feed override 0; set the feed to resume)",
                          [("controller/feed_override", 0.0)])

    def handle(self, action, client: str, authorized: bool = True) -> Result:
        """Validate and turn one action of a page into what to publish (module doc)."""
        if not isinstance(action, dict) or not isinstance(action.get("type"), str):
            return self._refuse(client, "?", "action: expected a JSON object with a 'type'")
        kind = action["type"]
        if kind == "heartbeat":
            self.heartbeat(client)
            return Result(True, "")
        if kind == "estop":
            with self.lock:
                # the page presses on three paths at once (module doc): the first press of
                # a latch starts the latency's clock and names the cause; the others repeat it
                if not (self.estop_latched and "estop" in self.sent):
                    self.estop_why = f"E-stop pressed on the panel ({client})"
                    self.sent["estop"] = self.clock()
                    self.latency_ms.pop("estop", None)
                self.estop_latched = True
            return self._done(client, kind, True, "E-stop sent: the controller and the drives latch it",
                              [("estop", True)])
        handler = {"reset": self._reset, "program": self._program, "start": self._start, "feed": self._feed,
                   "jog": self._jog, "settings": self._settings}.get(kind)
        if handler is None:
            return self._refuse(client, kind, f"type: must be one of estop, reset, program, start, feed, jog, "
                                              f"settings, heartbeat; got {kind!r}")
        if not authorized:
            return self._refuse(client, kind, "not authorized: control needs the panel's token (view only)")
        if self.restarting:           # the old graph would get it, or a second graph start
            return self._refuse(client, kind, f"{kind}: the graph is restarting (reset); try again when it runs")
        if self.estop_latched and kind != "reset":
            return self._refuse(client, kind, f"E-stop latched ({self.estop_why}): reset first")
        unreached = self._unreached(kind)
        if unreached is not None:
            return self._refuse(client, kind, unreached)
        try:
            message, publish, restart = handler(action, client)
        except ValueError as exc:
            return self._refuse(client, kind, str(exc))
        return self._done(client, kind, True, message, publish, restart)

    def malformed(self, client: str, why: str) -> Result:
        """A message of a page that is not an action (panel_app.parse_action): refused, logged."""
        return self._refuse(client, "?", why)

    def refused_request(self, client: str, why: str) -> None:
        """A request the web side refused before any action (a foreign Host or Origin): logged."""
        self._refuse(client, "request", why)

    # -------------------------------------------------------------- the actions
    def _reset(self, action, client):
        if not self.can_reset:
            raise FieldError("reset", "the E-stop is latched in the controller and the drives of this run; "
                                      "start a new run (pkm-run), or let pkm-panel start the graph (--start)")
        with self.lock:
            self.estop_latched, self.estop_why, self.jog = False, "", None
            self.latency_ms.clear()
            self.sent.clear()
            self.restarting = True
            self._forget_the_run()
        # the panel's latched estop is taken back first: the new run's nodes would get it
        return "reset: a new run starts", [("estop", False)], True

    def restarted(self) -> None:
        """The old graph of a reset has ended (its braked states and "stopped" statuses,
        which would latch the panel again, are over): listen to the new one."""
        with self.lock:
            self._forget_the_run()
            self.restarting = False

    def _forget_the_run(self) -> None:
        self.status = (0, "restarting", {})
        self.pose = self.reference = self.state = self.state_clock = None
        self.poses.clear()
        self.references.clear()
        self.diagnostics.clear()
        self.cia402.clear()
        self.plot.clear()
        self.last_plot_ns = None

    def _program(self, action, client):
        text, name = action.get("text"), action.get("name") or "program"
        if not isinstance(text, str) or not text.strip():
            raise FieldError("program", "text must be non-empty G-code")
        if len(text.encode()) > PROGRAM_MAX_BYTES:
            raise FieldError("program", f"at most {PROGRAM_MAX_BYTES} bytes, got {len(text.encode())}")
        with self.lock:
            start = self.reference or self.model.home
        segments = gcode_segments(text, self.model.space, start)   # ValueError: the line and the word
        if not segments:
            raise FieldError("program", "no motion in it")
        with self.lock:
            self.program = (str(name)[:80], text, len(segments))
        return f"program {name!s:.80} loaded: {len(segments)} moves (start sends it to the planner)", [], False

    def _holding(self, what: str) -> None:
        level, message, values = self.status
        mode = values.get("mode")
        if mode != "holding" or self.jog is not None:
            raise FieldError(what, f"the machine must be holding still, it is "
                                   f"{'jogging' if self.jog is not None else mode or 'not reporting yet'}")

    def _start(self, action, client):
        with self.lock:
            self._holding("start")
            if self.program is None:
                raise FieldError("start", "load a program first")
            name, text, moves = self.program
            self.sent["trajectory"] = self.clock()
        return f"program {name} sent to the planner ({moves} moves)", [("program", text)], False

    def _feed(self, action, client):
        value = action.get("percent")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 100.0:
            raise FieldError("feed", f"percent must be a number in [0, 100], got {value!r}")
        with self.lock:
            self.sent["feed_override"] = self.clock()
        return f"feed override {value:g} %", [("controller/feed_override", float(value) / 100.0)], False

    def _jog(self, action, client):
        axis, step = action.get("axis"), action.get("step")
        axes = self.model.axes
        if axis not in axes:
            raise FieldError("jog", f"axis must be one of {list(axes)}, got {axis!r}")
        k = axes.index(axis)
        bound = JOG_MAX_RAD if axis in self.model.angular else JOG_MAX_M
        unit = "rad" if axis in self.model.angular else "m"
        if isinstance(step, bool) or not isinstance(step, (int, float)) or not (0.0 < abs(step) <= bound):
            raise FieldError("jog", f"step must be a number with 0 < |step| <= {bound:g} {unit}, got {step!r}")
        with self.lock:
            self._holding("jog")
            if self.reference is None:
                raise FieldError("jog", "no reference from the controller yet")
            target = list(self.reference)
            target[k] += float(step)
            if k < len(self.model.box):
                lo, hi = self.model.box[k]
                if not lo <= target[k] <= hi:
                    raise FieldError("jog", f"{axis} would reach {target[k]:.4f} {unit}, outside the workspace "
                                            f"[{lo:g}, {hi:g}] {unit}")
            self.jog = {"client": client, "target": target, "since": self.clock()}
            self.heartbeats.setdefault(client, self.clock())
            self.sent["trajectory"] = self.clock()
        return f"jog {axis} {step:+g} {unit}", [("goal", target)], False

    def _settings(self, action, client):
        changes = action.get("changes")
        if not isinstance(changes, dict) or not changes:
            raise FieldError("settings", "changes must be a non-empty object {name: value}")
        for name, value in changes.items():
            check_setting(name, value)
        with self.lock:
            values = self.status[2]
        if "strategy" not in values:
            raise FieldError("settings", "the controller has not reported its settings yet")
        current = ControllerConfig(**{k: values[k] for k in RUNTIME_SETTINGS}, dt_s=values["dt_s"])
        # the rule of the running controller itself, on a scratch core with its settings
        ControllerCore(self.model.machine, current).change_settings(changes)
        with self.lock:
            self.sent["settings"] = self.clock()
        text = ", ".join(f"{k}={v}" for k, v in changes.items())
        return f"settings sent: {text}", [("controller/settings", json.dumps(changes))], False

    # ------------------------------------------------------------------- log
    def _done(self, client, kind, ok, message, publish=(), restart=False) -> Result:
        entry = {"wall_s": time.time(), "client": client, "type": kind, "ok": ok, "message": message}
        with self.lock:
            self.actions.append(entry)
        if self.log_line is not None:
            self.log_line(entry)
        return Result(ok, message, list(publish), restart)

    def _refuse(self, client, kind, message) -> Result:
        return self._done(client, kind, False, message)
