"""The direct engine (``pkm-run --engine direct``, studies by default): a lockstep
scenario's loops in one process without a transport.

In lockstep the graph is deterministic: the plant publishes the state of step k and
waits for the command stamped k (sim_hw_node's docstring). The same sans-IO loops the
nodes run (sim_loop.SimLoop, the Gough sensor's and the laser tracker's
sensor_loop, node_loop.ControllerLoop), built from the same parameters by the nodes'
own declarations (pkm_common.params.ParameterValues over the run's params/<node>.yaml),
hand each other their messages' bytes through a queue in the order the graph
delivers them: so the run is the graph's, every command and true pose bit for bit
(tests/bringup/test_direct_engine.py compares every lockstep scenario).

What is the graph's and not here: the transport (DDS, discovery, the recorder's
subscriptions), the wall-clock watchdogs (nothing can stall between two loops that
call each other), the markers (for a viewer of the live graph), the nodes' logs (one
file, logs/direct.log), and in a run without a recording the messages nobody reads:
/clock, the plant's diagnostics, controller/reference and controller/status (the log
has their errors), and metrology/pose unless the controller feeds the Gough's pose
back (its DKM is then not solved: the sensor's summary says ``dkm_run: false``, its
``solved`` count is 0). The run directory is the same: params, summaries, run.json,
the bag (rosbag2 MCAP through the recorder's own tap path, pkm_recording.tap,
written by a process of its own as the graph's recorder is: direct_recording, which
also solves the Gough's DKM pose where the controller does not read it:
direct_beside), so that pkm-report, pkm-replay and the DataFrames read it; or, for a study's run whose
bag would be removed once read, no bag: the messages kept in memory
(pkm_recording.memory) and the metrics taken from them (run_scenario's
``recording``).

Refused, with the reason: realtime scenarios (the plant steps on a clock), hardware
other than sim_hw (a drive interface's bus and its drives are processes of their
own) and scenarios that name operators (nodes that would command the run through the
graph): run them as a graph.
"""

from __future__ import annotations

import collections
import dataclasses
import time
from pathlib import Path

from rclpy.serialization import serialize_message
from std_msgs.msg import Bool, String

from pkm_bringup.direct_beside import PoseBeside
from pkm_bringup.direct_recording import MemoryRecorder, Recorder, RecorderProcess, bag_recorder
from pkm_bringup.graph import RunFailed
from pkm_bringup.scenario import START_TOPIC, Scenario, run_node_name, start_signal
from pkm_common import topics
from pkm_common.conversions import diagnostic_bytes, trajectory_bytes, trajectory_fields
from pkm_common.credential import RunKey, Signer, Verifier
from pkm_common.files import write_summary
from pkm_common.params import ParameterValues, declare_like
from pkm_controller.config import ControllerConfig
from pkm_controller.configuration import NODE_PARAMETERS, core_from_parameters
from pkm_controller.node_loop import ControllerLoop
from pkm_gough_sensor.sensor_loop import GoughSensorLoop, LaserLoop, declare_gough_sensor, declare_laser_tracker
from pkm_recording.memory import MemoryRecording
from pkm_common.runner import start_up_frozen
from pkm_sim_hw.parameters import declare_settings
from pkm_sim_hw.sim_loop import SimLoop
from pkm_sim_hw.step_streams import StepStreams
from pkm_trajectory.planning import PLAN_CACHE_SIZE, declare_planner
from pkm_trajectory.program import program_events_text

__all__ = ["DirectRun", "refusal", "run_direct"]

FLUSH_STEPS = 200            # the bag takes the records in batches of about this many steps (the graph's 0.2 s)
PROGRESS_STEPS = 100


def refusal(s: Scenario) -> str:
    """Why the direct engine cannot run ``s``, or "" when it can."""
    if s.mode != "lockstep":
        return (f"mode {s.mode}: the direct engine runs lockstep scenarios only (a realtime plant steps on a "
                "clock, its controller on its own); run it as a graph (without --engine direct)")
    if s.hardware != "sim":
        return (f"hardware {s.hardware}: the direct engine simulates sim_hw only (a drive interface's bus and its "
                "drives are processes of their own); run it as a graph (without --engine direct)")
    if s.operators:
        return (f"operators {s.operators}: the direct engine has no graph for them to command the run through; "
                "run it as a graph (without --engine direct)")
    return ""


class Topic:
    """One topic between the loops: a publication is recorded and queued for each reader."""

    __slots__ = ("queue", "readers", "tap", "index", "clock")

    def __init__(self, queue: collections.deque, recorder: Recorder | RecorderProcess | MemoryRecorder | None,
                 name: str, relative: str):
        self.queue, self.readers = queue, []
        self.tap = None if recorder is None else recorder.tap
        self.index = None if recorder is None else recorder.index(name, relative)
        self.clock = time.time_ns

    def publish(self, data: bytes) -> None:
        if self.tap is not None:
            self.tap.add_indexed(self.index, data, self.clock())
        for reader in self.readers:
            self.queue.append((reader, data))


class _Log:
    """The nodes' log lines, one file (the graph: logs/<node>.log)."""

    def __init__(self, path: Path):
        self.file = open(path, "a", encoding="utf-8")      # noqa: SIM115 - closed by DirectRun.close

    def line(self, node: str, level: str, text: str) -> None:
        self.file.write(f"[{level}] [{node}]: {text}\n")


class _Ports:
    """What the loops ask of their shells (sim_loop.SimPorts, node_loop.ControllerPorts,
    sensor_loop.SensorPorts), answered by the run's wiring: the graph of a run, whose
    every topic has the one publisher pkm-run starts."""

    def __init__(self, run: DirectRun, node: str):
        self.run, self.node = run, node

    def log_info(self, text: str) -> None:
        self.run.log.line(self.node, "INFO", text)

    def log_error(self, text: str) -> None:
        self.run.log.line(self.node, "ERROR", text)

    def diagnostics(self, stamp_ns: int, level: int, name: str, message: str, values: dict,
                    topic: str = topics.DIAGNOSTICS) -> None:
        self.run.topic(topic).publish(diagnostic_bytes(stamp_ns, name, level, message, values))


class _SimPorts(_Ports):
    def publish_diagnostics(self, stamp_ns: int, level: int, message: str, values: dict) -> None:
        self.diagnostics(stamp_ns, level, self.node, message, values)

    def publish_markers(self, segments, stamp_ns: int) -> None:
        """Markers are for a viewer of the live graph: not made here."""

    def report_refusal(self, refusal, topic: str, text: str, plant_step: int, now_ns: int) -> None:
        values = {"topic": topic, "reason": refusal.reason, "cause": str(refusal.cause),
                  "stamp_ns": refusal.stamp_ns, "sender": refusal.sender or "unknown",
                  "plant_step": plant_step, "stopped": refusal.stop}
        self.diagnostics(now_ns, 2, "sim_hw/refused", refusal.reason, values, topics.DRIVES_REFUSED)
        self.log_error(text)

    def command_publishers(self) -> list[str]:
        return [self.run.names["controller"]]

    def load_senders(self) -> list[str]:
        return []

    def after_cycle(self) -> None:
        self.run.after_step()

    def run_finished(self) -> None:
        """The loop ends when the queue is empty (the last state answered)."""


class _ControllerPorts(_Ports):
    def __init__(self, run: DirectRun, node: str):
        super().__init__(run, node)
        self.command = run.topic(topics.DRIVES_COMMAND)
        self.publish_command = self.command.publish
        self.publish_reference_bytes = run.topic(topics.CONTROLLER_REFERENCE).publish

    def resend_command(self, command: bytes) -> None:
        for reader in self.command.readers:            # not recorded: the bag holds one per stamp
            self.command.queue.append((reader, command))

    def publish_status(self, stamp_ns: int, level: int, message: str, values: dict) -> None:
        self.diagnostics(stamp_ns, level, "controller", message, values, topics.CONTROLLER_STATUS)

    def publish_event(self, text: str) -> None:
        self.run.topic(topics.CONTROLLER_EVENTS).publish(serialize_message(String(data=text)))

    def publish_estop(self) -> None:
        self.run.estop()

    def after_cycle(self) -> None:
        """The recorder's batches follow the plant's steps."""

    def input_publishers(self, topic: str) -> list[str]:
        return [self.run.names["gough_sensor" if topic.startswith("metrology/") else self.run.machine_node]]

    def topic_senders(self, topic: str) -> list[str]:
        senders = {topics.TRAJECTORY: "trajectory", START_TOPIC: "bringup_monitor"}
        return [self.run.names[senders[topic]]] if topic in senders else []


class _SensorPorts(_Ports):
    def __init__(self, run: DirectRun, node: str):
        super().__init__(run, node)
        self.publish_struts = run.topic(topics.METROLOGY_STRUTS).publish
        self.publish_pose = run.topic(topics.METROLOGY_POSE).publish

    def error(self, message: str, values: dict) -> None:
        self.log_error(message)
        self.diagnostics(max(int(values.get("stamp_ns", 0)), 0), 2, f"{self.node}: metrology", message, values)


_FIELDS: collections.OrderedDict = collections.OrderedDict()     # id(samples) -> (samples, point fields)


def _trajectory_bytes(space, samples, stamp_ns: int, signer) -> bytes:
    """The trajectory of a plan as trajectory_node publishes it (conversions.trajectory_bytes),
    signed; its points' fields made once per plan the planner keeps
    (planning.PLAN_CACHE_SIZE): a study's runs send the same points, each run with its
    own stamp and credential."""
    found = _FIELDS.get(id(samples))
    if found is None or found[0] is not samples:
        found = _FIELDS[id(samples)] = (samples, trajectory_fields(space, samples.position, samples.velocity,
                                                                   samples.acceleration))
        while len(_FIELDS) > PLAN_CACHE_SIZE:
            _FIELDS.popitem(last=False)
    return trajectory_bytes(space, samples.time_s, None, None, None, stamp_ns, signer, fields=found[1])


def controller_loop(params: dict, ports) -> ControllerLoop:
    """The run's ControllerLoop as controller_node configures it from the same
    parameters (declare_like on each, then core_from_parameters). Without its warm-up:
    that keeps a real-time loop's first cycles from loading or allocating on first use,
    and a lockstep run has no deadline (a study's run saved ~1.2 ms of ~100)."""
    node = ParameterValues(params)
    values = {name: declare_like(node, name, default) for name, default in NODE_PARAMETERS.items()}
    config = ControllerConfig(**{f.name: declare_like(node, f.name, f.default)
                              for f in dataclasses.fields(ControllerConfig)})
    core = core_from_parameters(values["machine"], config)
    loop = ControllerLoop(core, values, ports, Verifier.from_file(values["credential_file"]))
    loop.active = True
    loop.pairing.reset_watchdog()
    return loop


class DirectRun:
    """A lockstep scenario's loops wired to each other (see the module doc)."""

    def __init__(self, s: Scenario, run_dir: Path, params: dict, recording: MemoryRecording | None = None):
        self.s, self.run_dir, self.params = s, run_dir, params
        self.machine_node = s.machine_node
        self.names = {name: run_node_name(s, name) for name in (*params, "bringup_monitor")}
        self.queue: collections.deque = collections.deque()
        self.topics: dict[str, Topic] = {}
        self.log = _Log(run_dir / "logs" / "direct.log")
        self.recorder = None
        if s.record and recording is not None:
            self.recorder = MemoryRecorder(recording)
        elif s.record:
            recorder = params["recorder"]
            self.recorder = bag_recorder(recorder["output"], recorder.get("compression", "lz4"))
        self.steps_since_flush = 0
        self.summaries = {}              # node -> (its summary path, the summary's function)
        try:
            self._wire(s, params)
        except BaseException:            # a refused configuration, an interrupt: nothing left open
            self.log.file.close()
            if self.recorder is not None:
                self.recorder.abandon()
            raise

    def _wire(self, s: Scenario, params: dict) -> None:
        """The loops, each built by its node's declarations, and who reads what."""
        # the plant
        sim_params = params[self.machine_node]
        # (markers are for a viewer of the live graph: none is made here)
        settings = dataclasses.replace(declare_settings(ParameterValues(sim_params)), publish_markers=False)
        self.plant = settings.plant
        streams = StepStreams(self.plant, settings.machine.model.task_space, self.topic(topics.TRUE_POSE),
                              self.topic(topics.DRIVES_STATE), self.topic(topics.CLOCK))
        self.sim = SimLoop(settings, streams, _SimPorts(self, self.machine_node))      # (it writes its summary)
        # the instruments
        sensor = None
        if "gough_sensor" in params:
            settings = declare_gough_sensor(ParameterValues(params["gough_sensor"]))
            sensor = GoughSensorLoop(settings.model, _SensorPorts(self, "gough_sensor"))
            self.topic(topics.TRUE_POSE).readers.append(sensor.on_true_pose)
            self.summaries["gough_sensor"] = (settings.summary_path, sensor.summary)
        if "laser_tracker" in params:
            settings = declare_laser_tracker(ParameterValues(params["laser_tracker"]))
            laser = LaserLoop(settings.model, self.topic(topics.LASER_POINT).publish,
                              _Ports(self, "laser_tracker").log_error, topics.LASER_POINT)
            self.topic(topics.TRUE_POSE).readers.append(laser.on_true_pose)
            self.summaries["laser_tracker"] = (settings.summary_path, laser.summary)
        # the controller
        self.controller = controller_loop(params["controller"], _ControllerPorts(self, "controller"))
        self.summaries["controller"] = (params["controller"].get("summary_path", ""), self.controller.summary)
        self.topic(topics.DRIVES_STATE).readers.append(self.controller.on_state)
        self.topic(topics.DRIVES_COMMAND).readers.append(self.sim.on_command)
        metrology = self.controller.core.strategy.metrology_topic
        if metrology:
            self.topic(metrology).readers.append(self.controller.on_metrology)
        # what nobody records or reads is not made (a run without a recording): the
        # clock, the controller's reference and status, and the Gough's DKM pose unless
        # the controller feeds it back (the struts are its readings; ~8 us of a ~60 us step)
        if self.unread(topics.CLOCK):
            streams.clock = None
        if self.unread(topics.DIAGNOSTICS):
            self.sim.cadences = ()                   # its diagnostics, their only side work here
        self.controller.publishes_reference = not self.unread(topics.CONTROLLER_REFERENCE)
        self.controller.publishes_status = not self.unread(topics.CONTROLLER_STATUS)
        beside = None
        if sensor is not None:
            sensor.solves_pose = not self.unread(topics.METROLOGY_POSE)
            if sensor.solves_pose and not self.topic(topics.METROLOGY_POSE).readers and \
                    isinstance(self.recorder, RecorderProcess):
                # recorded, not read: solved by the bag's writer, beside the loop (direct_beside)
                beside = PoseBeside(sensor, lambda run: _SensorPorts(run, "gough_sensor"), self.topic_name)
                sensor.solves_pose = False
                self.summaries["gough_sensor"] = (self.summaries["gough_sensor"][0],
                                                  lambda: _with_beside(sensor.summary(), self.recorder.work_summary))
        if self.recorder is not None:
            self.recorder.start(beside)

    def unread(self, relative: str) -> bool:
        """Whether nothing records or reads a topic of the run (once it is wired)."""
        found = self.topics.get(relative)
        return self.recorder is None and (found is None or not found.readers)

    def topic(self, relative: str) -> Topic:
        """The run's topic of a catalogue name (made on first use)."""
        found = self.topics.get(relative)
        if found is None:
            found = self.topics[relative] = Topic(self.queue, self.recorder, self.topic_name(relative), relative)
        return found

    def topic_name(self, relative: str) -> str:
        """The full name of a topic of the catalogue in the run's namespace."""
        return relative if relative.startswith("/") else f"{self.s.namespace.rstrip('/')}/{relative}"

    def after_step(self) -> None:
        self.steps_since_flush += 1
        if self.recorder is not None and self.steps_since_flush >= FLUSH_STEPS:
            self.steps_since_flush = 0
            self.recorder.flush()

    def estop(self) -> None:
        """The controller latched estop: the plant brakes, the controller stays stopped."""
        self.topic(topics.ESTOP).publish(serialize_message(Bool(data=True)))
        self.queue.append((lambda _: self.sim.on_estop(True), b""))
        self.queue.append((lambda _: self.controller.on_estop(True), b""))

    def plan(self) -> None:
        """The program planned as trajectory_node plans it at start, published signed to
        the controller (which waits for it and the start); a rejected program is the
        run's failure."""
        settings = declare_planner(ParameterValues(self.params["trajectory"]))
        try:
            text = Path(settings.program_file).read_text(encoding="utf-8")
            samples = settings.plan_program(text, settings.config.model.home.tolist())
        except Exception as exc:              # noqa: BLE001 - the planner's every refusal, named
            raise RunFailed(f"the planner rejected the program {settings.program_file}: {exc}") from None
        stamp_ns = time.time_ns()
        path = self.params["trajectory"].get("credential_file", "")
        signer = Signer(RunKey.read(path), self.names["trajectory"]) if path else None
        data = _trajectory_bytes(settings.config.model.task_space, samples, stamp_ns, signer)
        self.topic(topics.TRAJECTORY).publish(data)
        if samples.events:
            self.topic(topics.PROGRAM_EVENTS).publish(serialize_message(String(
                data=program_events_text(stamp_ns, samples.events))))
        self.controller.on_trajectory(data)

    def start(self) -> None:
        """pkm-run's latched start signal (the controller waits for it)."""
        data = start_signal(Path(self.params["controller"]["credential_file"]), self.names["bringup_monitor"])
        self.topic(START_TOPIC).publish(data)
        self.controller.on_start(data)

    def run(self, progress, deadline: float) -> None:
        """From the start to the plant's last step, its last state answered."""
        if "trajectory" in self.params:
            self.plan()
        self.start()
        self.sim.publish_state()
        queue, sim, plant = self.queue, self.sim, self.plant
        next_progress = 0
        while queue:
            reader, data = queue.popleft()
            reader(data)
            if plant.k >= next_progress:
                next_progress = plant.k + PROGRESS_STEPS
                progress.update(plant.t)
                if time.monotonic() > deadline:
                    raise RunFailed(f"timeout_s: the run did not end within {self.s.timeout_s:g} s (wall clock)")
        if not sim.run.finished:
            raise RunFailed(f"the loop stopped at step {plant.k} of {sim.duration_steps}: no message left to "
                            f"answer (see {self.run_dir / 'logs' / 'direct.log'})")

    def close(self) -> None:
        """The nodes' summaries and the bag, whatever happened (an interrupted run's too)."""
        try:
            if not self.sim.run.finished:
                self.sim.write_summary()            # interrupted: what was done so far
            recorded = None
            try:
                if self.recorder is not None:
                    recorded = self.recorder.close()     # first: the work beside the loop is in its summary
            finally:
                work = getattr(self.recorder, "work_summary", None) or {}
                for line in work.get("lines", ()):      # the failures solved beside the loop, in their order
                    self.log.file.write(line + "\n")
                if work.get("lines_dropped"):
                    self.log.line("gough_sensor", "ERROR", f"... and {work['lines_dropped']} more lines like these")
                for path, summary in self.summaries.values():
                    if path:
                        write_summary(path, summary(), lambda text: self.log.line("direct", "ERROR", text))
            if recorded is not None:
                write_summary(self.params["recorder"]["summary_path"], recorded,
                              lambda text: self.log.line("recorder", "ERROR", text))
        finally:
            self.log.file.close()


def _with_beside(summary: dict, work: dict | None) -> dict:
    """The sensor's summary with the DKM's counts of its copy beside the loop
    (direct_beside.PoseBeside): as if its loop had solved them."""
    if work is None:                             # the writer gave none (it failed): the loop's counts
        return summary
    return {**summary, "solved": work["solved"], "failed": work["failed"], "dkm_run": True,
            "published": {**summary["published"], "metrology/pose": work["published_pose"]}}


def run_direct(s: Scenario, run_dir: Path, params: dict, progress, codes: dict, interruption=None,
               reserve=None, recording: MemoryRecording | None = None) -> dict:
    """The scenario in the direct engine (the runners' signature, graph.run_processes);
    fills and returns ``codes`` (0 per node that ran). ``recording``: a recorded
    scenario's messages go there instead of to a bag. Raises RunFailed."""
    why = refusal(s)
    if why:
        raise RunFailed(why)
    run = None
    try:
        try:
            run = DirectRun(s, run_dir, params, recording)
        except ValueError as exc:                 # a refused configuration is the run's failure
            raise RunFailed(f"refused configuration: {exc}") from None
        # the process's heap out of the cyclic collector for the loop (a study's worker's
        # full collections took ~0.12 s of its ~1.3 s runs)
        with start_up_frozen(collect=False):
            run.run(progress, time.monotonic() + s.timeout_s)
        progress.update(s.duration_s)
    finally:
        progress.done()
        if reserve is not None:
            reserve.release()
        if run is not None:
            run.close()
    codes.update({name: 0 for name in params})
    return codes
