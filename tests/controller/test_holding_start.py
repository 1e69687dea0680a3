"""A machine at rest stays at rest when its controller starts: the PID laws have no
gravity term but their integral, which starts holding the nominal model's static forces
(pkm_controller.tuning.holding_integral), and a change of law while holding does not drop the
load. Started at zero, the integral let every machine under a PID law fall 0.3-3.7 mm at power-on
(ARCHI 4 mm at the panel's 8 Hz, a following-error trip with a few late commands in a
suite's browser test; MoM3's joint PIDs tripped on a false encoder slip)."""

import numpy as np
import pytest

from pkm_controller.config import ControllerConfig

from pkm_controller.controller import ControllerCore
from pkm_controller.strategies import REGISTRY
from pkm_kinematics import load_machine
from pkm_sim_hw.parameters import PLANTS
from pkm_sim_hw.plant import Plant, PlantParameters

DT = 0.004
# hexapod8 and MoM3 at 1 kHz: at 250 Hz their joint PIDs' stiffest modes (mass ratio 2.77 and
# 2.16) are unstable at 20 Hz, and the controller refuses them (test_gain_stability.py)
DT_OF = {"hexapod8": 0.001, "mom3": 0.001}
ENCODER_STRATEGIES = [name for name, s in REGISTRY.items() if not s.uses_metrology]
MACHINES = ["archi", "sliding_star", "orthoglide", "mom3", "hexapod8", "genhexkins"]
# hexapod8's joint PIDs need a slower integral (test_gain_stability.py)
INTEGRAL_TIME_S = {"hexapod8": 0.1}


def hold(machine, core: ControllerCore, steps: int, switch_at: int | None = None, to: str = "") -> tuple:
    """``steps`` cycles from rest at home; at ``switch_at`` the strategy changes to ``to``.
    Returns (largest move of the tool from home (m), the first command)."""
    plant = PLANTS.get(machine.kind, Plant)(machine, PlantParameters(dt_s=core.config.dt_s))
    out = plant.output()
    home = np.array(out.tool_pose[:3])
    worst, first = 0.0, None
    for k in range(steps):
        if k == switch_at:
            core.change_settings({"strategy": to})
        forces = core.update(out.stamp_ns, out.encoder_positions, out.encoder_velocities, out.applied_forces)
        assert not core.stopped, core.stop_reason
        out = plant.step(forces)
        first = np.array(forces) if first is None else first
        worst = max(worst, float(np.linalg.norm(np.array(out.tool_pose[:3]) - home)))
    return worst, first


@pytest.mark.parametrize("name", MACHINES)
@pytest.mark.parametrize("strategy", ENCODER_STRATEGIES)
def test_a_machine_at_rest_stays_still_when_its_controller_starts(name, strategy):
    machine = load_machine(name)
    dt = DT_OF.get(name, DT)
    core = ControllerCore(machine, ControllerConfig(strategy=strategy, distribution="pseudo_inverse", dt_s=dt,
                                                    integral_time_s=INTEGRAL_TIME_S.get(name, 0.05)))
    worst, first = hold(machine, core, round(0.5 / dt))
    assert worst < 10e-6, f"{name} {strategy}: the tool moved {worst * 1e6:.0f} um"
    # the first command holds the platform: J^T f = H(x, 0), the plant's own model
    # (the nominal one here), the second reader of the forces
    plant = PLANTS.get(machine.kind, Plant)(machine, PlantParameters(dt_s=dt))
    x0 = machine.model.home
    wrench = np.asarray(plant.dynamics.static_forces(x0))
    jac = np.asarray(machine.model.jacobian(x0))
    # (within 1e-3: the PD part answers the encoders' quantisation, ARCHI's 4e-4)
    assert np.abs(jac.T @ first - wrench).max() < 1e-3 * np.abs(wrench).max()


@pytest.mark.parametrize("before, after", [("computed_torque", "decentralized_projected"),
                                           ("joint_pid", "cartesian_pid"), ("cartesian_pid", "computed_torque")])
def test_a_change_of_law_while_holding_keeps_the_load(before, after):
    """The integral belongs to the law: a new law's starts holding where the machine
    is (zero for computed torque, whose H(x, v) holds it)."""
    machine = load_machine("archi")
    core = ControllerCore(machine, ControllerConfig(strategy=before, dt_s=DT))
    worst, _ = hold(machine, core, round(0.6 / DT), switch_at=round(0.3 / DT), to=after)
    assert worst < 10e-6, f"{before} -> {after}: the tool moved {worst * 1e6:.0f} um"


def test_without_an_integral_a_pid_starts_from_nothing():
    """integral_time_s 0: the P(D) law of the paper (ARCHI Fig. 12's "no integral"), no
    hidden holding term: the first command is the PD's on a zero error."""
    machine = load_machine("archi")
    core = ControllerCore(machine, ControllerConfig(strategy="joint_pid", integral_time_s=0.0, dt_s=DT))
    worst, first = hold(machine, core, 10)
    assert np.abs(first).max() < 1.0 and worst > 10e-6          # and the machine sags
