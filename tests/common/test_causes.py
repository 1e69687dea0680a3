"""The plant's status word (pkm_common.causes.PlantStatus): written and read in one
place, and the words of bags recorded before it was typed still read the same."""

import pytest

from pkm_common.causes import (HELD_COMMAND_UNKNOWN, RUNNING, PlantState, PlantStatus, TripCause, plant_status,
                               safe_stop_status, setpoint_held_status)


@pytest.mark.parametrize("status", [RUNNING, setpoint_held_status(0), setpoint_held_status(4_000_000),
                                    *(safe_stop_status(cause) for cause in TripCause)])
def test_a_status_reads_back_from_its_word(status):
    assert plant_status(status.word()) == status


@pytest.mark.parametrize("word, expected", [
    # the literal words sim_hw wrote into frame_id before the status was typed (older bags)
    ("", PlantStatus()),
    ("safe_stop:watchdog", PlantStatus(PlantState.SAFE_STOP, TripCause.WATCHDOG)),
    ("safe_stop:input_refused", PlantStatus(PlantState.SAFE_STOP, TripCause.INPUT_REFUSED)),
    ("setpoint_held:12000000", PlantStatus(PlantState.SETPOINT_HELD, held_ns=12_000_000)),
    # a newer plant's words: a stop stays a stop, a held setpoint stays held
    ("safe_stop:cosmic_ray", PlantStatus(PlantState.SAFE_STOP, TripCause.PLANT_SAFE_STOP)),
    ("setpoint_held", PlantStatus(PlantState.SETPOINT_HELD, held_ns=HELD_COMMAND_UNKNOWN)),
    ("setpoint_held:soon", PlantStatus(PlantState.SETPOINT_HELD, held_ns=HELD_COMMAND_UNKNOWN)),
    ("world", PlantStatus()),
])
def test_the_words_on_the_wire(word, expected):
    status = plant_status(word)
    assert status == expected, status
    assert status.stopped == (expected.state is PlantState.SAFE_STOP)
