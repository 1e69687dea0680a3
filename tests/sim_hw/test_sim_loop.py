"""sim_hw's loop without ROS (pkm_sim_hw.sim_loop): the lockstep and the command
authority decided on bytes, with the node's ports replaced by a recorder of calls.
The node's own tests (test_sim_hw_node.py) run the same code through DDS."""

from pkm_common.causes import TripCause, plant_status
from pkm_common.cdr import JointStateDecoder, JointStateEncoder
from pkm_common.credential import RunKey, Signer, Verifier
from pkm_common.sources import AllowedSenders
from pkm_kinematics import load_machine
from pkm_sim_hw.authority import CommandGate
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_sim_hw.sim_loop import SimHwSettings, SimLoop
from pkm_sim_hw.step_streams import StepStreams

ARCHI = load_machine("archi")
CONTROLLER = "/pkm/controller"


class Wire:
    """A publisher: keeps what was published."""

    def __init__(self):
        self.sent = []

    def publish(self, data: bytes) -> None:
        self.sent.append(data)


class Ports:
    def __init__(self):
        self.publishers = [CONTROLLER]
        self.loads = []
        self.refusals, self.diagnostics, self.errors, self.ended = [], [], [], False
        self.infos = []

    def publish_diagnostics(self, stamp_ns, level, message, values):
        self.diagnostics.append((level, message))

    def publish_markers(self, segments, stamp_ns):
        pass

    def report_refusal(self, refusal, topic, text, plant_step, now_ns):
        self.refusals.append(refusal)

    def command_publishers(self):
        return list(self.publishers)

    def load_senders(self):
        return list(self.loads)

    def after_cycle(self):
        pass

    def run_finished(self):
        self.ended = True

    def log_info(self, text):
        self.infos.append(text)

    def log_error(self, text):
        self.errors.append(text)


def lockstep_loop(duration_steps=0, load_sources=(), key=None, encoder_offsets_m=()):
    plant = Plant(ARCHI, PlantParameters(dt_s=0.001, encoder_offsets_m=encoder_offsets_m))
    settings = SimHwSettings(ARCHI, plant, lockstep=True, command_timeout_s=1.0, sync_error_limit=12,
                             gate=CommandGate("", True, 20_000_000), publish_markers=False,
                             duration_s=duration_steps * 0.001, duration_steps=duration_steps, summary_path="",
                             shutdown_on_finish=True, load_senders=AllowedSenders("load", load_sources, "load_sources"),
                             credentials=Verifier(key))
    state = Wire()
    ports = Ports()
    loop = SimLoop(settings, StepStreams(plant, ARCHI.model.task_space, Wire(), state, Wire()), ports)
    return loop, state, ports


def command(stamp_ns, effort=(0.0, 0.0, 0.0, 0.0)):
    return JointStateEncoder(list(ARCHI.model.leg_names), fields=("effort",)).encode(stamp_ns, effort=effort)


def test_each_answer_steps_the_plant_once_and_publishes_the_next_state():
    loop, state, ports = lockstep_loop(duration_steps=3)
    loop.publish_state()                                   # step 0, as the node does at start
    decode = JointStateDecoder("drives/state").decode
    for k in range(3):
        assert decode(state.sent[-1]).stamp_ns == k * 1_000_000
        loop.on_command(command(k * 1_000_000))
        loop.on_command(command(k * 1_000_000))            # the same answer again: stale, not a step
    # stale twice; the third repeat came after the last step: a finished run takes nothing
    assert loop.plant.k == 3 and loop.counts["stale_commands"] == 2
    assert ports.ended and loop.run.finished and not ports.refusals
    # the loop's start is logged once, at the first command (what a test or an operator waits for)
    assert [t for t in ports.infos if t.startswith("loop started")] == ["loop started: the first command, at step 0"]


def test_commands_before_homing_are_refused_saying_so_and_nothing_moves():
    """Incremental encoders (encoder_offsets_m) read the machine's positions only once it
    is homed (pkm_sim_hw.homing.home): until then no drive command is applied."""
    loop, state, ports = lockstep_loop(encoder_offsets_m=(0.01, 0.02, 0.03, 0.04))
    loop.publish_state()
    x = list(loop.plant.x)
    loop.on_command(command(0, effort=(100.0, -100.0, 50.0, 0.0)))
    assert loop.plant.k == 0 and loop.plant.x == x and not loop.plant.stopped
    assert ports.refusals[0].reason.startswith("not homed: drive commands are refused until the machine is homed")
    assert not ports.refusals[0].stop


def test_a_command_ahead_of_the_plant_is_refused_and_the_plant_brakes():
    loop, state, ports = lockstep_loop()
    loop.publish_state()
    loop.on_command(command(5_000_000))
    assert loop.plant.stopped and loop.plant.stop_cause == TripCause.INPUT_REFUSED
    assert "ahead of the plant's step" in ports.refusals[0].reason
    loop.publish_state()
    assert plant_status(JointStateDecoder("drives/state").decode(state.sent[-1]).frame_id).cause \
        == TripCause.INPUT_REFUSED                          # the status word says why


def test_a_second_publisher_is_an_intruder_named_in_the_refusal():
    loop, _, ports = lockstep_loop()
    loop.publish_state()
    loop.on_command(command(0))                            # the controller is the one publisher
    assert loop.plant.k == 1 and not loop.plant.stopped
    ports.publishers.append("/rogue")
    loop.on_command_matched(2)
    assert loop.plant.stopped and loop.plant.stop_cause == TripCause.INTRUDER
    assert ports.refusals[-1].sender == "/rogue" and loop.run.intruder_named


def test_a_publisher_matched_before_the_graph_names_it_is_refused_counted_then_named():
    loop, _, ports = lockstep_loop()
    loop.publish_state()
    loop.on_command(command(0))
    loop.on_command_matched(2)                             # discovery has not named it yet
    assert loop.plant.stopped and loop.plant.stop_cause == TripCause.INTRUDER
    assert ports.refusals[-1].reason == f"2 publishers on drives/command (only {CONTROLLER} may)"
    assert not loop.run.intruder_named
    ports.publishers.append("/rogue")
    loop.on_watchdog()                                     # the graph knows it now: named
    assert ports.refusals[-1].sender == "/rogue" and loop.run.intruder_named


def test_a_load_from_a_node_the_run_did_not_name_stops_the_machine():
    """A rogue's 4,900 N load (under the plant's bound) moved the tool 15.4 mm at up to
    998 mm/s: now refused, and the plant brakes (cause intruder), the rogue named."""
    loop, _, ports = lockstep_loop(load_sources=("/pkm/bringup_monitor", "/pkm/panel"))
    loop.publish_state()
    loop.on_command(command(0))
    ports.loads = ["/pkm/rogue"]
    loop.on_load((4900.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert loop.plant.stopped and loop.plant.stop_cause == TripCause.INTRUDER
    assert ports.refusals[0].reason.startswith("/pkm/rogue publishes on load (only /pkm/bringup_monitor, /pkm/panel")
    assert loop.plant.load == [0.0, 0.0, 0.0] or not any(loop.plant.load)        # never applied
    assert ports.refusals[0].sender == "/pkm/rogue"
    # a named operator's load within the bounds is applied
    loop, _, ports = lockstep_loop(load_sources=("/pkm/panel",))
    ports.loads = ["/pkm/panel"]
    loop.on_load((100.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert not loop.plant.stopped and loop.plant.load[0] == 100.0


def test_with_the_runs_key_a_load_needs_its_credential(tmp_path):
    """A rogue under an allowed name (the graph names only /pkm/panel) sends a load
    without the run's credential: refused, the plant brakes (cause intruder); the
    panel's signed load is applied."""
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import serialize_message

    from pkm_common.conversions import signed_message
    key = RunKey.create(tmp_path / "credential.key")
    msg = WrenchStamped()
    msg.wrench.force.x = 100.0
    loop, _, ports = lockstep_loop(load_sources=("/pkm/panel",), key=key)
    ports.loads = ["/pkm/panel"]
    loop.on_load_message(signed_message(Signer(key, "/pkm/panel"), "load", msg))
    assert not loop.plant.stopped and loop.plant.load[0] == 100.0
    msg.wrench.force.x, msg.header.frame_id = 4900.0, "world"
    loop.on_load_message(serialize_message(msg))
    assert loop.plant.stopped and loop.plant.stop_cause == TripCause.INTRUDER
    assert ports.refusals[-1].reason == "load: no credential (pkm-cred/1 tag) in the message"
    assert loop.plant.load[0] == 100.0 and loop.summary()["intruder"] == "unknown"
    ports.loads = ["/pkm/panel", "/pkm/rogue"]            # the graph names the rogue later
    loop.on_watchdog()
    assert loop.summary()["intruder"] == "/pkm/rogue"
