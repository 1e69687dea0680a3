"""The CiA 402 drive profile (IEC 61800-7-201), both sides, without any transport.

The power state machine of a servo drive (its Figure "state machine" and Tables
"statusword" and "controlword"): a master drives it with the controlword (0x6040),
the drive reports it in the statusword (0x6041). The same objects exist over CANopen
and over EtherCAT (CoE), so nothing here knows a bus.

- ``State`` and ``decode_state(statusword)``: the eight states, by the standard's
  bit masks; ``statusword(state, ...)`` the word a drive sends in a state.
- ``Command`` and ``decode_command(controlword, previous)``: the six device control
  commands (fault reset on the rising edge of bit 7); ``CONTROLWORD`` their words.
- ``DriveStateMachine``: the drive's side, the transitions 0-16 of the standard.
- ``MasterSequencer``: the master's side, the next controlword towards a wanted
  state (fault reset edges included).
- ``Mode`` (0x6060/0x6061), ``HomingStatus`` (statusword bits 10, 12, 13 in homing
  mode) and ``ERROR_CODES`` (0x603F and EMCY error codes of CiA 301/402 used here).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = ["State", "STATE_BITS", "decode_state", "statusword", "Command", "CONTROLWORD", "decode_command",
           "Transition", "DriveStateMachine", "MasterSequencer", "Mode", "HomingStatus", "homing_status", "homing_bits",
           "ERROR_CODES", "error_text", "QuickStopOption", "SW", "CW"]


class SW(enum.IntFlag):
    """Statusword (0x6041) bits."""

    READY_TO_SWITCH_ON = 1 << 0
    SWITCHED_ON = 1 << 1
    OPERATION_ENABLED = 1 << 2
    FAULT = 1 << 3
    VOLTAGE_ENABLED = 1 << 4
    QUICK_STOP = 1 << 5               # 0: a quick stop is active
    SWITCH_ON_DISABLED = 1 << 6
    WARNING = 1 << 7
    REMOTE = 1 << 9                   # the controlword is obeyed
    TARGET_REACHED = 1 << 10
    INTERNAL_LIMIT = 1 << 11
    MODE_SPECIFIC_12 = 1 << 12        # homing: attained; CST/CSP/CSV: target value followed
    MODE_SPECIFIC_13 = 1 << 13        # homing: error; CSP: following error


class CW(enum.IntFlag):
    """Controlword (0x6040) bits."""

    SWITCH_ON = 1 << 0
    ENABLE_VOLTAGE = 1 << 1
    QUICK_STOP = 1 << 2               # 0: quick stop
    ENABLE_OPERATION = 1 << 3
    MODE_SPECIFIC_4 = 1 << 4          # homing: start (rising edge)
    FAULT_RESET = 1 << 7              # rising edge
    HALT = 1 << 8


class State(enum.IntEnum):
    """The power states of a CiA 402 drive."""

    NOT_READY_TO_SWITCH_ON = 0
    SWITCH_ON_DISABLED = 1
    READY_TO_SWITCH_ON = 2
    SWITCHED_ON = 3
    OPERATION_ENABLED = 4
    QUICK_STOP_ACTIVE = 5
    FAULT_REACTION_ACTIVE = 6
    FAULT = 7

    @property
    def label(self) -> str:
        """The standard's name ("operation enabled")."""
        return self.name.lower().replace("_", " ")


# (mask, value) of each state in the statusword (CiA 402 Table "state coding")
STATE_BITS = {
    State.NOT_READY_TO_SWITCH_ON: (0x4F, 0x00),
    State.SWITCH_ON_DISABLED: (0x4F, 0x40),
    State.READY_TO_SWITCH_ON: (0x6F, 0x21),
    State.SWITCHED_ON: (0x6F, 0x23),
    State.OPERATION_ENABLED: (0x6F, 0x27),
    State.QUICK_STOP_ACTIVE: (0x6F, 0x07),
    State.FAULT_REACTION_ACTIVE: (0x4F, 0x0F),
    State.FAULT: (0x4F, 0x08),
}


def decode_state(word: int) -> State | None:
    """The state a statusword reports; None for a word that codes none (a drive that
    sends one is broken or not a CiA 402 drive)."""
    for state, (mask, value) in STATE_BITS.items():
        if word & mask == value:
            return state
    return None


def statusword(state: State, *, mode_bits: int = 0, target_reached: bool = False,
               internal_limit: bool = False, warning: bool = False, remote: bool = True) -> int:
    """The statusword a drive in ``state`` sends: the state's bits, voltage enabled
    while the power stage is on, and the flags (``mode_bits``: bits 12 and 13)."""
    word = STATE_BITS[state][1]
    if state in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED):
        word |= SW.QUICK_STOP                 # 1: no quick stop
    if state in (State.SWITCHED_ON, State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE,
                 State.FAULT_REACTION_ACTIVE):
        word |= SW.VOLTAGE_ENABLED
    word |= mode_bits & (SW.MODE_SPECIFIC_12 | SW.MODE_SPECIFIC_13)
    word |= (SW.TARGET_REACHED if target_reached else 0) | (SW.INTERNAL_LIMIT if internal_limit else 0)
    word |= (SW.WARNING if warning else 0) | (SW.REMOTE if remote else 0)
    return int(word)


class Command(enum.Enum):
    """The device control commands of the controlword."""

    SHUTDOWN = "shutdown"
    SWITCH_ON = "switch on"                   # also "disable operation" (the same bits)
    ENABLE_OPERATION = "enable operation"     # "switch on + enable operation" from ready to switch on
    DISABLE_VOLTAGE = "disable voltage"
    QUICK_STOP = "quick stop"
    FAULT_RESET = "fault reset"


CONTROLWORD = {
    Command.SHUTDOWN: 0x06,
    Command.SWITCH_ON: 0x07,
    Command.ENABLE_OPERATION: 0x0F,
    Command.DISABLE_VOLTAGE: 0x00,
    Command.QUICK_STOP: 0x02,
    Command.FAULT_RESET: 0x80,
}


def decode_command(word: int, previous: int = 0) -> Command | None:
    """The command of a controlword (CiA 402 Table "command coding"), ``previous`` the
    word received before it (fault reset is bit 7's rising edge; a bit 7 held high is
    ignored). None: no command (bits 0-3 code none of them)."""
    if word & CW.FAULT_RESET and not previous & CW.FAULT_RESET:
        return Command.FAULT_RESET
    if word & 0x02 == 0x00:
        return Command.DISABLE_VOLTAGE
    if word & 0x06 == 0x02:
        return Command.QUICK_STOP
    if word & 0x07 == 0x06:
        return Command.SHUTDOWN
    if word & 0x0F == 0x07:
        return Command.SWITCH_ON
    if word & 0x0F == 0x0F:
        return Command.ENABLE_OPERATION
    return None


class QuickStopOption(enum.IntEnum):
    """Quick stop option code (0x605A), the values a torque drive supports: stop, then
    switch on disabled (1, 2) or stay in quick stop active (5, 6)."""

    SLOW_DOWN_RAMP_THEN_DISABLED = 1
    QUICK_STOP_RAMP_THEN_DISABLED = 2
    SLOW_DOWN_RAMP_STAY = 5
    QUICK_STOP_RAMP_STAY = 6

    @property
    def stays(self) -> bool:
        """The drive stays in quick stop active (and may be enabled again: transition 16)."""
        return self >= 5


@dataclass(frozen=True)
class Transition:
    """A state change of the drive: the standard's transition number, from, to."""

    number: int
    source: State
    target: State


_S = State
# (state, command) -> (transition number, next state), CiA 402 Figure "state machine"
_TRANSITIONS = {
    (_S.SWITCH_ON_DISABLED, Command.SHUTDOWN): (2, _S.READY_TO_SWITCH_ON),
    (_S.READY_TO_SWITCH_ON, Command.SWITCH_ON): (3, _S.SWITCHED_ON),
    (_S.READY_TO_SWITCH_ON, Command.ENABLE_OPERATION): (3, _S.SWITCHED_ON),    # then 4 on the same word
    (_S.SWITCHED_ON, Command.ENABLE_OPERATION): (4, _S.OPERATION_ENABLED),
    (_S.OPERATION_ENABLED, Command.SWITCH_ON): (5, _S.SWITCHED_ON),            # disable operation
    (_S.SWITCHED_ON, Command.SHUTDOWN): (6, _S.READY_TO_SWITCH_ON),
    (_S.READY_TO_SWITCH_ON, Command.QUICK_STOP): (7, _S.SWITCH_ON_DISABLED),
    (_S.READY_TO_SWITCH_ON, Command.DISABLE_VOLTAGE): (7, _S.SWITCH_ON_DISABLED),
    (_S.OPERATION_ENABLED, Command.SHUTDOWN): (8, _S.READY_TO_SWITCH_ON),
    (_S.OPERATION_ENABLED, Command.DISABLE_VOLTAGE): (9, _S.SWITCH_ON_DISABLED),
    (_S.SWITCHED_ON, Command.DISABLE_VOLTAGE): (10, _S.SWITCH_ON_DISABLED),
    (_S.SWITCHED_ON, Command.QUICK_STOP): (10, _S.SWITCH_ON_DISABLED),
    (_S.OPERATION_ENABLED, Command.QUICK_STOP): (11, _S.QUICK_STOP_ACTIVE),
    (_S.QUICK_STOP_ACTIVE, Command.DISABLE_VOLTAGE): (12, _S.SWITCH_ON_DISABLED),
    (_S.FAULT, Command.FAULT_RESET): (15, _S.SWITCH_ON_DISABLED),
    (_S.QUICK_STOP_ACTIVE, Command.ENABLE_OPERATION): (16, _S.OPERATION_ENABLED),
}


class DriveStateMachine:
    """The drive's side: its state, moved by controlwords (``on_controlword``), by its
    own events (``initialised``, ``fault``, ``fault_reaction_done``,
    ``quick_stop_done``). Each returns the transitions it made (the standard's
    numbers), empty when the word asked for nothing the state allows (the drive
    ignores it, as the standard says)."""

    def __init__(self, quick_stop_option: QuickStopOption = QuickStopOption.QUICK_STOP_RAMP_THEN_DISABLED):
        self.quick_stop_option = QuickStopOption(quick_stop_option)
        self.state = State.NOT_READY_TO_SWITCH_ON         # transition 0: power on, self-test
        self.last_controlword = 0
        self.error_code = 0                               # 0x603F: the fault's code, kept until reset

    @property
    def torque_enabled(self) -> bool:
        """The drive follows its target (only in operation enabled)."""
        return self.state is State.OPERATION_ENABLED

    def _go(self, number: int, target: State) -> Transition:
        made = Transition(number, self.state, target)
        self.state = target
        return made

    def initialised(self) -> list[Transition]:
        """Transition 1: the self-test passed."""
        if self.state is State.NOT_READY_TO_SWITCH_ON:
            return [self._go(1, State.SWITCH_ON_DISABLED)]
        return []

    def on_controlword(self, word: int) -> list[Transition]:
        command = decode_command(word, self.last_controlword)
        self.last_controlword = word
        if command is None:
            return []
        step = _TRANSITIONS.get((self.state, command))
        if step is None:
            return []
        if step[0] == 16 and not self.quick_stop_option.stays:
            return []                                     # transition 16 only for option codes 5-8
        made = [self._go(*step)]
        if command is Command.FAULT_RESET:
            self.error_code = 0
        if step[0] == 3 and command is Command.ENABLE_OPERATION:
            made.append(self._go(4, State.OPERATION_ENABLED))   # "switch on + enable operation"
        return made

    def fault(self, code: int) -> list[Transition]:
        """Transition 13: a fault (``code``, 0x603F) in any state but a fault one; the
        fault reaction starts. A second fault during it keeps the first code."""
        if self.state in (State.FAULT, State.FAULT_REACTION_ACTIVE):
            return []
        self.error_code = int(code)
        return [self._go(13, State.FAULT_REACTION_ACTIVE)]

    def fault_reaction_done(self) -> list[Transition]:
        """Transition 14: the fault reaction (the stop, the brake) is complete."""
        if self.state is State.FAULT_REACTION_ACTIVE:
            return [self._go(14, State.FAULT)]
        return []

    def quick_stop_done(self) -> list[Transition]:
        """Transition 12 at the end of a quick stop, for option codes 1-3 (else the
        drive stays in quick stop active)."""
        if self.state is State.QUICK_STOP_ACTIVE and not self.quick_stop_option.stays:
            return [self._go(12, State.SWITCH_ON_DISABLED)]
        return []


# the path towards operation enabled, one command per state (the master's side)
_TOWARDS_ENABLED = {
    State.SWITCH_ON_DISABLED: Command.SHUTDOWN,
    State.READY_TO_SWITCH_ON: Command.SWITCH_ON,
    State.SWITCHED_ON: Command.ENABLE_OPERATION,
    State.OPERATION_ENABLED: Command.ENABLE_OPERATION,
    State.QUICK_STOP_ACTIVE: Command.DISABLE_VOLTAGE,     # 12, then the path again (16 not assumed)
}


# towards switched on (power on, brake closed): the same path, stopping there
_TOWARDS_SWITCHED_ON = {**_TOWARDS_ENABLED, State.SWITCHED_ON: Command.SWITCH_ON,
                        State.OPERATION_ENABLED: Command.SWITCH_ON}                  # 5: disable operation


class MasterSequencer:
    """The master's side for one drive: ``next(state, target)``, the controlword to
    send this cycle to bring a drive in ``state`` towards ``target`` (operation
    enabled, switched on, switch on disabled or quick stop active). From a fault it
    sends the fault reset's rising edge (a word without bit 7 first when the last one
    had it)."""

    def __init__(self):
        self.last = 0

    def next(self, state: State | None, target: State) -> int:
        word = self._word(state, target)
        self.last = word
        return word

    def _word(self, state: State | None, target: State) -> int:
        if target is State.QUICK_STOP_ACTIVE:
            return CONTROLWORD[Command.QUICK_STOP]
        if target is State.SWITCH_ON_DISABLED:
            return CONTROLWORD[Command.DISABLE_VOLTAGE]
        if target not in (State.OPERATION_ENABLED, State.SWITCHED_ON):
            raise ValueError(f"target: must be operation enabled, switched on, switch on disabled or quick stop "
                             f"active, got {target.label}")
        if state is State.FAULT:
            return CONTROLWORD[Command.DISABLE_VOLTAGE] if self.last & CW.FAULT_RESET \
                else CONTROLWORD[Command.FAULT_RESET]
        path = _TOWARDS_ENABLED if target is State.OPERATION_ENABLED else _TOWARDS_SWITCHED_ON
        if state in path:
            return CONTROLWORD[path[state]]
        return CONTROLWORD[Command.DISABLE_VOLTAGE]       # not ready, fault reaction, unknown: wait safely


class Mode(enum.IntEnum):
    """Modes of operation (0x6060, shown in 0x6061)."""

    NO_MODE = 0
    PROFILE_POSITION = 1
    VELOCITY = 2
    PROFILE_VELOCITY = 3
    PROFILE_TORQUE = 4
    HOMING = 6
    INTERPOLATED_POSITION = 7
    CYCLIC_SYNC_POSITION = 8
    CYCLIC_SYNC_VELOCITY = 9
    CYCLIC_SYNC_TORQUE = 10

    @property
    def supported_bit(self) -> int:
        """Its bit in "supported drive modes" (0x6502)."""
        return 1 << (self.value - 1) if self.value > 0 else 0


class HomingStatus(enum.Enum):
    """Homing mode's statusword bits 13, 12, 10 (CiA 402 homing mode)."""

    IN_PROGRESS = (0, 0, 0)
    INTERRUPTED = (0, 0, 1)            # or not started
    ATTAINED = (0, 1, 0)               # the home found, the target not reached yet
    COMPLETED = (0, 1, 1)
    ERROR_MOVING = (1, 0, 0)
    ERROR_STOPPED = (1, 0, 1)


def homing_status(word: int) -> HomingStatus:
    bits = (int(bool(word & SW.MODE_SPECIFIC_13)), int(bool(word & SW.MODE_SPECIFIC_12)),
            int(bool(word & SW.TARGET_REACHED)))
    try:
        return HomingStatus(bits)
    except ValueError:                 # 1, 1, x: reserved by the standard: an error
        return HomingStatus.ERROR_STOPPED


def homing_bits(status: HomingStatus) -> tuple[int, bool]:
    """(mode bits 12-13, target reached) of a homing status, for ``statusword``."""
    error, attained, reached = status.value
    return (SW.MODE_SPECIFIC_13 if error else 0) | (SW.MODE_SPECIFIC_12 if attained else 0), bool(reached)


# Error codes (0x603F, EMCY) of CiA 301 and CiA 402 that the drives here raise or report
ERROR_CODES = {
    0x0000: "no error",
    0x2310: "continuous over-current",
    0x2320: "short circuit or earth leakage",
    0x3210: "DC link over-voltage",
    0x4310: "drive over-temperature",
    0x7305: "incremental encoder 1 broken",
    0x8110: "CAN overrun (objects lost)",
    0x8130: "life guard or heartbeat error",
    0x8250: "RPDO timeout",
    0x8611: "following error",
    0x8612: "reference limit",
    0xFF00: "manufacturer specific",
}


def error_text(code: int) -> str:
    """"0x2310 continuous over-current": the code and what the standard calls it."""
    name = ERROR_CODES.get(code) or ERROR_CODES.get(code & 0xFF00) or "unknown error code"
    return f"0x{code:04X} {name}"
