"""sim_hw's run record without ROS: steps counted once each, refusals counted by
topic with the first intruder kept, and the diagnostics and summary read from the
plant they describe."""

import numpy as np

from pkm_common.causes import TripCause
from pkm_kinematics import load_machine
from pkm_sim_hw.authority import Refusal
from pkm_sim_hw.plant import Plant
from pkm_sim_hw.run_record import RunRecord, true_pose_components


def test_the_record_counts_each_step_once_and_names_the_first_intruder():
    plant = Plant(load_machine("archi"))
    run = RunRecord("archi", lockstep=False)
    for ns in (0, 0, 0, 500_000, 1_000_000, 1_000_000):     # discovery repeats of step 0, a repeat of step 2
        run.published(ns)
    assert run.steps_published == 3 and run.last_published_ns == 1_000_000
    assert run.refused(Refusal("stamp ahead", TripCause.INPUT_REFUSED), "drives/command") == \
        "refused command: stamp ahead"
    run.refused(Refusal("/rogue publishes", TripCause.INTRUDER, sender="/rogue"), "drives/command")
    run.refused(Refusal("/other publishes", TripCause.INTRUDER, sender="/other"), "drives/command")
    assert run.refused(Refusal("1e9 N", TripCause.LOAD_REFUSED), "load") == "refused load: 1e9 N"
    assert run.counts["refused_commands"] == 3 and run.counts["refused_loads"] == 1
    assert run.intruder == "/rogue"

    level, message, values = run.diagnostics(plant, plant.output())
    assert (level, message, values["mode"], values["intruder"]) == (0, "running", "realtime", "/rogue")
    plant.safe_stop("refused command: /rogue publishes", TripCause.INTRUDER)
    level, message, values = run.diagnostics(plant, plant.output())
    assert level == 2 and message == "stopped: refused command: /rogue publishes" and values["cause"] == "intruder"

    run.first_command_wall = 100.0
    summary = run.summary(plant, now=102.0)
    assert summary["wall_s"] == 2.0 and summary["stopped"] and summary["refused_commands"] == 3
    assert summary["published"] == {"drives/state": 3, "platform/true_pose": 3, "/clock": 3}
    before_any_command = RunRecord("archi", lockstep=True).summary(plant, now=5.0)
    assert before_any_command["wall_s"] == 0.0 and before_any_command["steps_per_s"] is None


def test_the_true_pose_of_a_planar_plant_is_its_tool_pose():
    plant = Plant(load_machine("archi"))
    out = plant.output()
    position, orientation = true_pose_components(plant.machine.task_space, out)
    x, y, theta = out.tool_pose[:3]
    assert np.allclose(position[:2], [x, y])
    # a rotation about z by theta as a quaternion (x, y, z, w)
    assert np.allclose(np.abs(orientation), np.abs([0.0, 0.0, np.sin(theta / 2), np.cos(theta / 2)]), atol=1e-12)


def test_an_intruder_counted_before_the_graph_names_it_is_named_by_the_next_refusal():
    """The matched event can count a second publisher on drives/command before
    discovery names its node: the plant stops at once, unnamed; the first refusal
    that names it (sim_hw's watchdog asks the graph every 0.1 s) names it, and a later
    one does not rename it."""
    run = RunRecord("archi", lockstep=False)
    assert not run.intruder_named
    run.refused(Refusal("2 publishers on drives/command", TripCause.INTRUDER), "drives/command")
    assert run.intruder == "unknown" and not run.intruder_named
    run.refused(Refusal("/pkm/rogue publishes", TripCause.INTRUDER, sender="/pkm/rogue"), "drives/command")
    run.refused(Refusal("/pkm/other publishes", TripCause.INTRUDER, sender="/pkm/other"), "drives/command")
    assert run.intruder == "/pkm/rogue" and run.intruder_named
    assert run.counts["refused_commands"] == 3
