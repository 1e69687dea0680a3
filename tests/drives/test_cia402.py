"""The CiA 402 state machine (pkm_drives.cia402) against canopen's own CiA 402 tables
(canopen.profiles.p402.State402: the statusword masks and the master's transition
table), an independent implementation of the same standard."""

import pytest
from canopen.profiles.p402 import Homing, OperationMode, State402

from pkm_drives.cia402 import (CONTROLWORD, Command, DriveStateMachine, HomingStatus, MasterSequencer, Mode,
                               QuickStopOption, State, decode_command, decode_state, homing_bits, homing_status,
                               statusword)

NAMES = {s: s.label.upper() for s in State}


def test_decode_state_agrees_with_canopen_on_every_word():
    for word in range(0x10000):
        theirs = next((name for name, (mask, bits) in State402.SW_MASK.items() if word & mask == bits), None)
        mine = decode_state(word)
        assert (NAMES[mine] if mine is not None else None) == theirs, hex(word)


@pytest.mark.parametrize("state", list(State))
def test_statusword_codes_its_state(state):
    word = statusword(state)
    assert decode_state(word) is state, hex(word)
    assert word & 0x200, "remote bit"
    # voltage enabled (bit 4) exactly while the power stage is on
    powered = state in (State.SWITCHED_ON, State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE,
                        State.FAULT_REACTION_ACTIVE)
    assert bool(word & 0x10) == powered


def _drive_in(state: State, option=QuickStopOption.QUICK_STOP_RAMP_STAY) -> DriveStateMachine:
    drive = DriveStateMachine(option)
    drive.state = state
    return drive


@pytest.mark.parametrize("source,target,word", [(a, b, w) for (a, b), w in State402.TRANSITIONTABLE.items()
                                                 if a not in ("START", "NOT READY TO SWITCH ON",
                                                              "FAULT REACTION ACTIVE")])
def test_every_commanded_transition_of_canopens_master_table(source, target, word):
    """Each controlword canopen's master sends for a transition moves the drive there."""
    state = next(s for s in State if NAMES[s] == source)
    drive = _drive_in(state)
    drive.on_controlword(word)
    assert NAMES[drive.state] == target, f"{source} --0x{word:04X}--> {drive.state.label}"


def test_transition_numbers_and_automatic_transitions():
    drive = DriveStateMachine(QuickStopOption.QUICK_STOP_RAMP_THEN_DISABLED)
    assert drive.state is State.NOT_READY_TO_SWITCH_ON
    assert [t.number for t in drive.initialised()] == [1]
    path = [(Command.SHUTDOWN, [2]), (Command.SWITCH_ON, [3]), (Command.ENABLE_OPERATION, [4]),
            (Command.QUICK_STOP, [11])]
    for command, numbers in path:
        assert [t.number for t in drive.on_controlword(CONTROLWORD[command])] == numbers, command
    assert drive.state is State.QUICK_STOP_ACTIVE and not drive.torque_enabled
    assert drive.on_controlword(CONTROLWORD[Command.ENABLE_OPERATION]) == []     # 16 needs option 5-8
    assert [t.number for t in drive.quick_stop_done()] == [12]
    # "switch on + enable operation" from ready to switch on: 3 then 4 on one word
    drive.on_controlword(CONTROLWORD[Command.SHUTDOWN])
    assert [t.number for t in drive.on_controlword(0x0F)] == [3, 4]
    assert drive.torque_enabled


def test_fault_latches_until_a_rising_edge_of_bit_7():
    drive = _drive_in(State.OPERATION_ENABLED)
    assert [t.number for t in drive.fault(0x2310)] == [13]
    assert drive.fault(0x8611) == [] and drive.error_code == 0x2310          # the first code kept
    assert [t.number for t in drive.fault_reaction_done()] == [14]
    assert drive.on_controlword(CONTROLWORD[Command.ENABLE_OPERATION]) == []  # ignored in fault
    assert [t.number for t in drive.on_controlword(0x80)] == [15]
    assert drive.state is State.SWITCH_ON_DISABLED and drive.error_code == 0
    # bit 7 held high is no second reset, and the commands still decode
    assert decode_command(0x86, previous=0x80) is Command.SHUTDOWN
    assert decode_command(0x80, previous=0x80) is Command.DISABLE_VOLTAGE


def test_master_sequencer_brings_a_drive_from_fault_to_operation_enabled():
    """The sequencer and the drive machine together, one controlword per cycle."""
    drive = _drive_in(State.FAULT)
    drive.error_code = 0x7305
    drive.last_controlword = 0x80                  # the master's last word had bit 7: an edge needs a 0 first
    master = MasterSequencer()
    master.last = 0x80
    seen = []
    for _ in range(8):
        drive.on_controlword(master.next(drive.state, State.OPERATION_ENABLED))
        seen.append(drive.state)
        if drive.state is State.OPERATION_ENABLED:
            break
    assert seen == [State.FAULT, State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON, State.SWITCHED_ON,
                    State.OPERATION_ENABLED]
    assert master.next(State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE) == 0x02
    with pytest.raises(ValueError, match="target"):
        master.next(State.SWITCHED_ON, State.FAULT)


def test_modes_and_homing_bits_match_canopen():
    for mode in Mode:
        if mode is not Mode.NO_MODE:
            name = OperationMode.CODE2NAME[int(mode)]
            assert OperationMode.SUPPORTED[name] == mode.supported_bit, mode
    names = {HomingStatus.IN_PROGRESS: "IN PROGRESS", HomingStatus.INTERRUPTED: "INTERRUPTED",
             HomingStatus.ATTAINED: "ATTAINED", HomingStatus.COMPLETED: "TARGET REACHED",
             HomingStatus.ERROR_MOVING: "ERROR VELOCITY IS NOT ZERO",
             HomingStatus.ERROR_STOPPED: "ERROR VELOCITY IS ZERO"}
    for status, name in names.items():
        bits, reached = homing_bits(status)
        word = statusword(State.OPERATION_ENABLED, mode_bits=bits, target_reached=reached)
        mask, value = Homing.STATES[name]
        assert word & mask == value, (status, hex(word))
        assert homing_status(word) is status
