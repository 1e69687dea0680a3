"""A virtual CiA 402 drive (pkm_drives.virtual_drive) driven by canopen's own CiA 402
master (canopen.BaseNode402) over python-can's virtual bus: SDO set-up, NMT, SYNC,
PDOs both ways, every transition of the state machine with the statusword the
standard gives after each, quick stop, faults, fault reset, modes."""

import itertools
import time

import can
import canopen
import pytest

from pkm_drives.cia402 import STATE_BITS, State, decode_state
from pkm_drives.drive_config import AxisScaling
from pkm_drives.virtual_drive import DEFAULT_EDS, MassAxes, VirtualMachine

NODE = 5
PERIOD_S = 0.005
SCALING = AxisScaling(counts_per_unit=1e6, rated_force=100.0, max_force=300.0)
_channels = itertools.count()


class Bench:
    """One drive on a bench (a mass on a rail), its master, and the SYNC."""

    def __init__(self, quick_stop_option: int = 2):
        channel = f"test_virtual_drive_{next(_channels)}"
        self.drive_net, self.master_net = (canopen.Network(can.Bus(interface="virtual", channel=channel))
                                           for _ in range(2))
        for net in (self.drive_net, self.master_net):
            net.NOTIFIER_CYCLE = 0.05           # its thread's receive timeout: how long disconnect waits
            net.connect()
        self.axes = MassAxes(1, mass_kg=5.0, friction_ns_per_m=20.0, dt_s=PERIOD_S)
        self.machine = VirtualMachine(self.drive_net, self.axes, [NODE], [SCALING])
        self.drive = self.machine.drives[0]
        self.node = canopen.BaseNode402(NODE, str(DEFAULT_EDS))
        # the defaults (0.2-0.8 s) are for a real bus; a loaded test machine may stall longer
        self.node.TIMEOUT_SWITCH_STATE_FINAL = self.node.TIMEOUT_SWITCH_STATE_SINGLE = 5.0
        self.node.TIMEOUT_CHECK_TPDO = self.node.TIMEOUT_SWITCH_OP_MODE = 5.0
        self.master_net.add_node(self.node)
        self.machine.boot()
        self.node.nmt.state = "PRE-OPERATIONAL"
        self.node.sdo[0x605A].raw = quick_stop_option
        self.node.setup_402_state_machine(read_pdos=True)
        self.node.nmt.state = "OPERATIONAL"
        self.node.rpdo[1].start(PERIOD_S)
        self.master_net.sync.start(PERIOD_S)

    def close(self):
        self.master_net.sync.stop()
        self.node.rpdo[1].stop()
        self.master_net.disconnect()
        self.drive_net.disconnect()
        assert self.machine.errors == [] and self.drive.errors == []

    def wait_state(self, state: State, timeout_s: float = 5.0) -> int:
        """The first statusword (from a TPDO) that codes ``state``."""
        end = time.monotonic() + timeout_s
        seen = []
        while time.monotonic() < end:
            word = self.node.check_statusword()
            if decode_state(word) is state:
                return word
            if not seen or seen[-1] != hex(word):
                seen.append(hex(word))
        raise AssertionError(f"no {state.label} within {timeout_s} s; statuswords seen: {seen}")

    def until(self, condition, what: str, timeout_s: float = 5.0) -> None:
        """TPDOs until ``condition()`` holds (AssertionError saying ``what`` after ``timeout_s``)."""
        end = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > end:
                raise AssertionError(f"not within {timeout_s} s: {what}; axes {self.axes.position} "
                                     f"{self.axes.velocity}, TPDO values {self.node.tpdo_values}")
            self.node.check_statusword()

    def command(self, word: int, state: State) -> int:
        self.node.controlword = word
        sw = self.wait_state(state)
        mask, value = STATE_BITS[state]
        assert sw & mask == value and sw & 0x200, (state, hex(sw))
        return sw


@pytest.fixture
def bench():
    b = Bench()
    yield b
    b.close()


def test_start_up_to_operation_enabled_and_torque_both_ways(bench):
    node = bench.node
    assert decode_state(node.check_statusword()) is State.SWITCH_ON_DISABLED      # transition 1 at boot
    node.op_mode = "CYCLIC SYNCHRONOUS TORQUE"
    assert node.op_mode == "CYCLIC SYNCHRONOUS TORQUE"
    # a torque before operation enabled moves nothing
    node.rpdo[1]["Target torque"].raw = 500
    bench.command(0x06, State.READY_TO_SWITCH_ON)                                 # 2
    sw = bench.command(0x07, State.SWITCHED_ON)                                   # 3
    assert sw & 0x10, "voltage enabled"
    time.sleep(10 * PERIOD_S)
    assert bench.axes.position == [0.0] and node.tpdo_values[0x6077] == 0
    bench.command(0x0F, State.OPERATION_ENABLED)                                  # 4
    deadline = time.monotonic() + 5.0
    while node.tpdo_values[0x6064] < 1000 and time.monotonic() < deadline:       # 1 mm
        node.check_statusword()
    # the drive applies 50 N (500 per mille of 100 N) and reports it; its position is the axis's
    assert node.tpdo_values[0x6077] == 500
    node.check_statusword()
    counts = node.tpdo_values[0x6064]
    assert counts >= 1000
    velocity = node.tpdo[2]["Velocity actual value"].raw
    assert velocity > 0
    # the limit (0x6072: 3000 per mille) clamps and says so (internal limit, bit 11)
    node.rpdo[1]["Target torque"].raw = 5000
    # the periodic RPDO carries it, a SYNC latches it, the next step applies it: a few SYNCs
    deadline = time.monotonic() + 5.0
    sw = node.check_statusword()
    while node.tpdo_values[0x6077] != 3000 and time.monotonic() < deadline:
        sw = node.check_statusword()
    assert node.tpdo_values[0x6077] == 3000 and sw & 0x800, (node.tpdo_values[0x6077], hex(sw))


def test_every_transition_with_its_statusword():
    bench = Bench(quick_stop_option=6)          # stays in quick stop active: transition 16 allowed
    try:
        bench.node.op_mode = "CYCLIC SYNCHRONOUS TORQUE"
        path = [(0x06, State.READY_TO_SWITCH_ON),    # 2
                (0x07, State.SWITCHED_ON),           # 3
                (0x0F, State.OPERATION_ENABLED),     # 4
                (0x07, State.SWITCHED_ON),           # 5
                (0x06, State.READY_TO_SWITCH_ON),    # 6
                (0x02, State.SWITCH_ON_DISABLED),    # 7 (quick stop)
                (0x06, State.READY_TO_SWITCH_ON),
                (0x00, State.SWITCH_ON_DISABLED),    # 7 (disable voltage)
                (0x06, State.READY_TO_SWITCH_ON), (0x07, State.SWITCHED_ON), (0x0F, State.OPERATION_ENABLED),
                (0x06, State.READY_TO_SWITCH_ON),    # 8
                (0x07, State.SWITCHED_ON), (0x0F, State.OPERATION_ENABLED),
                (0x00, State.SWITCH_ON_DISABLED),    # 9
                (0x06, State.READY_TO_SWITCH_ON), (0x07, State.SWITCHED_ON),
                (0x00, State.SWITCH_ON_DISABLED),    # 10 (disable voltage)
                (0x06, State.READY_TO_SWITCH_ON), (0x07, State.SWITCHED_ON),
                (0x02, State.SWITCH_ON_DISABLED),    # 10 (quick stop)
                (0x06, State.READY_TO_SWITCH_ON), (0x07, State.SWITCHED_ON), (0x0F, State.OPERATION_ENABLED),
                (0x02, State.QUICK_STOP_ACTIVE),     # 11
                (0x0F, State.OPERATION_ENABLED),     # 16
                (0x02, State.QUICK_STOP_ACTIVE),
                (0x00, State.SWITCH_ON_DISABLED)]    # 12 (disable voltage)
        for word, state in path:
            bench.command(word, state)
        # 13, 14: a fault in operation enabled; 15: the reset
        bench.command(0x06, State.READY_TO_SWITCH_ON)
        bench.command(0x07, State.SWITCHED_ON)
        bench.command(0x0F, State.OPERATION_ENABLED)
        bench.drive.inject("following_error")
        sw = bench.wait_state(State.FAULT)
        assert sw & 0x08 and not sw & 0x04, hex(sw)
        assert bench.node.sdo[0x603F].raw == 0x8611
        assert bench.node.sdo[0x1001].raw & 0x01
        bench.command(0x0F, State.FAULT)                 # a fault ignores other commands
        bench.command(0x80, State.SWITCH_ON_DISABLED)    # 15
        assert bench.node.sdo[0x603F].raw == 0
    finally:
        bench.close()


def test_quick_stop_brakes_and_option_2_ends_disabled(bench):
    node = bench.node
    node.op_mode = "CYCLIC SYNCHRONOUS TORQUE"
    node.rpdo[1]["Target torque"].raw = 800
    node.state = "OPERATION ENABLED"
    bench.until(lambda: bench.axes.velocity[0] >= 0.05, "moving at 50 mm/s")
    bench.node.controlword = 0x02
    bench.wait_state(State.QUICK_STOP_ACTIVE)         # seen for a SYNC at least
    bench.wait_state(State.SWITCH_ON_DISABLED)        # option 2: then disabled
    held = list(bench.axes.position)
    node.check_statusword()
    node.check_statusword()
    assert bench.axes.position == held and bench.axes.velocity == [0.0]


def test_fault_sends_emcy_and_latches_until_reset(bench):
    node = bench.node
    node.op_mode = "CYCLIC SYNCHRONOUS TORQUE"
    node.state = "OPERATION ENABLED"
    bench.drive.inject("over_current")
    bench.wait_state(State.FAULT)
    deadline = time.monotonic() + 5.0
    while not node.emcy.log and time.monotonic() < deadline:
        time.sleep(PERIOD_S)
    emcy = node.emcy.log[0] if node.emcy.log else None
    assert emcy and emcy.code == 0x2310 and emcy.register & 0x03 == 0x03, node.emcy.log
    node.state = "OPERATION ENABLED"                  # canopen's path: fault reset, then 2, 3, 4
    assert node.state == "OPERATION ENABLED"
    deadline = time.monotonic() + 5.0
    while not any(e.code == 0 for e in node.emcy.log) and time.monotonic() < deadline:
        time.sleep(PERIOD_S)
    assert node.emcy.log[-1].code == 0, "the reset is announced by an EMCY with code 0"


def test_homing_mode_is_shown_and_encoder_fault_freezes_the_position(bench):
    node = bench.node
    node.op_mode = "HOMING"
    assert node.op_mode == "HOMING" and node.sdo[0x6061].raw == 6
    node.op_mode = "CYCLIC SYNCHRONOUS TORQUE"
    node.rpdo[1]["Target torque"].raw = 300
    node.state = "OPERATION ENABLED"
    bench.until(lambda: bench.axes.position[0] >= 1e-3, "1 mm travelled")
    bench.drive.inject("encoder")
    bench.wait_state(State.FAULT)
    frozen = node.tpdo_values[0x6064]
    node.check_statusword()
    assert node.tpdo_values[0x6064] == frozen and node.sdo[0x603F].raw == 0x7305
