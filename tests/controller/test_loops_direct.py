"""The node's loops drivable without ROS (issue 41, "one loop, three shells"): the
controller's ControllerLoop and the plant's SimLoop exchanging their messages' bytes
in lockstep in one process, with ports that hand each publication to the other loop,
compute the same run as the controller core against the plant (closed_loop.run):
every command bit for bit. What a study engine without a graph builds on."""

from collections import deque

import numpy as np

from pkm_common.cdr import JointStateDecoder
from pkm_common.credential import Verifier
from pkm_common.sources import AllowedSenders
from pkm_controller.closed_loop import run as core_loop
from pkm_controller.config import ControllerConfig
from pkm_controller.configuration import NODE_PARAMETERS, core_from_parameters
from pkm_controller.node_loop import ControllerLoop
from pkm_controller.reference import Reference
from pkm_kinematics import load_machine
from pkm_sim_hw.authority import CommandGate
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_sim_hw.sim_loop import SimHwSettings, SimLoop
from pkm_sim_hw.step_streams import StepStreams

ARCHI = load_machine("archi")
PLANT, CONTROLLER = "/pkm/sim_hw", "/pkm/controller"


class Wire:
    """A topic between the loops: a publication is queued for its reader."""

    def __init__(self, queue: deque, reader=None):
        self.queue, self.reader = queue, reader

    def publish(self, data: bytes) -> None:
        if self.reader is not None:
            self.queue.append((self.reader, data))


class Ports:
    """Both loops' other ports: the graph as the two loops see it, nothing else."""

    def __init__(self, send_command):
        self.publish_command = self.resend_command = send_command

    def input_publishers(self, topic):
        return [PLANT]

    def topic_senders(self, topic):
        return [PLANT]

    def command_publishers(self):
        return [CONTROLLER]

    def load_senders(self):
        return []

    def log_error(self, text):
        raise AssertionError(text)

    def __getattr__(self, name):          # statuses, markers, logs, the tap's flush: not needed here
        return lambda *args, **kwargs: None


def _reference(steps: int) -> Reference:
    home = ARCHI.model.home.tolist()
    t = np.linspace(0.0, 0.5 * steps * 1e-3, 200)
    s = 0.5 - 0.5 * np.cos(np.pi * t / t[-1])             # 2 mm in x, rest to rest
    position = np.array([[home[0] + 0.002 * v, home[1], home[2]] for v in s])
    return Reference(t, position, np.gradient(position, t, axis=0))


def test_the_loops_without_ros_compute_the_core_loops_run_bit_for_bit():
    steps, config = 600, ControllerConfig(strategy="computed_torque", distribution="inf_norm")
    queue: deque = deque()
    controller = ControllerLoop(core_from_parameters("archi", config), {**NODE_PARAMETERS, "state_source": PLANT},
                                Ports(lambda data: queue.append((sim.on_command, data))))
    controller.active = True
    controller.core.set_trajectory(_reference(steps))
    plant = Plant(ARCHI, PlantParameters(dt_s=0.001))
    settings = SimHwSettings(ARCHI, plant, lockstep=True, command_timeout_s=1.0, sync_error_limit=12,
                             gate=CommandGate("", True, 20_000_000), publish_markers=False,
                             duration_s=steps * 1e-3, duration_steps=steps, summary_path="", shutdown_on_finish=True,
                             load_senders=AllowedSenders("load", ()), credentials=Verifier(None))
    streams = StepStreams(plant, ARCHI.model.task_space, Wire(queue), Wire(queue, controller.on_state), Wire(queue))
    sim = SimLoop(settings, streams, Ports(None))
    commands = []
    controller.ports.publish_command = lambda data: (commands.append(data), queue.append((sim.on_command, data)))
    sim.publish_state()
    while queue:
        reader, data = queue.popleft()
        reader(data)
    decode = JointStateDecoder("drives/command").decode
    direct = np.array([decode(c).effort for c in commands])

    _, log = core_loop(ARCHI, config, Plant(ARCHI, PlantParameters(dt_s=0.001)), steps, reference=_reference(steps))
    assert sim.run.finished and plant.k == steps and not controller.core.stopped, controller.core.stop_reason
    # the controller answers the last state too (step ``steps``, which the finished plant does not apply)
    assert direct.shape == (steps + 1, 4), direct.shape
    np.testing.assert_array_equal(direct[:steps], np.array(log.forces))       # bit for bit
    assert np.abs(direct).max() > 1.0                                   # the machine moved: forces, not zeros
