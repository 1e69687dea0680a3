"""A machine as built, for simulated calibrations: the nominal machine with seeded
errors on the parameters a calibration identifies, written as a machine file for the
plant (scenario ``machine``) while the controller keeps the nominal one (``model``).

A strut machine (strut_errors.StrutErrorModel) gets errors on every joint position and
every encoder's scale (the plant's ``link_length_errors``: its encoders read the true
length over 1 + e, so the scale error is e); its encoders' zeros stay exact (the plant
has no such error). The gauge (``strut_gauge``) stays nominal: the instrument's frame,
which the calibration takes as the machine's base frame, and the platform's rotation
about the measured point, which one point cannot see.
"""

from __future__ import annotations

import numpy as np

from .identify import gauge
from .machine_files import strut_machine_data
from .strut_errors import StrutErrorModel

__all__ = ["strut_gauge", "as_built_struts"]

FRAME = ("frame.x", "frame.y", "frame.z", "frame.rx", "frame.ry", "frame.rz")


def strut_gauge(model: StrutErrorModel, readings) -> tuple:
    """The parameters held at nominal by convention (identify.gauge): the instrument's
    frame, then the platform parameters that one point's readings at ``readings``
    (N, n) cannot identify beyond the ones before them."""
    return gauge(model.jacobian(np.zeros(model.size), readings), model.names, FRAME)


def as_built_struts(config, model: StrutErrorModel, held, seed: int, joint_std_m: float = 5e-4,
                    scale_std: float = 2e-4) -> tuple[dict, np.ndarray, list]:
    """(the as-built machine file's data, the true parameters, the plant's
    link_length_errors) of strut machine ``config`` (module doc)."""
    rng = np.random.default_rng(seed)
    truth = np.zeros(model.size)
    for k, name in enumerate(model.names):
        if name in held:
            continue
        if name.startswith(("a.", "b.")):
            truth[k] = rng.normal(0.0, joint_std_m)
        elif name.startswith("scale."):
            truth[k] = rng.normal(0.0, scale_std)
    scales = [float(truth[model.names.index(f"scale.{leg}")]) for leg in model.machine.leg_names]
    data = strut_machine_data(config, model.names, truth)
    data["description"] = f"{config.data.get('description', config.name)}, as built (seed {seed})"
    return data, truth, scales
