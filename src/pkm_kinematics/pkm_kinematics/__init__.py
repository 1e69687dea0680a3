"""pkm_kinematics: the pure numpy/scipy kinematics core of the PKM controller.

No rclpy import anywhere in this package: nodes call it, tests call it directly.

Models (bars between joints, built from ``config/machines/*.yaml``; ``machine.ParallelMachine``
is the interface they share):
  RailMachine           one bar per drive on a rail: planar (ARCHI, Sliding Star) or
                        translating (MoM3 linear Delta, Orthoglide), by configuration
  ParallelogramMachine  the Delta with two bars per parallelogram (MoM3 §4.1's imperfect case)
  StrutMachine          actuated struts: the Gough-Stewart hexapod, redundant hexapods
  GoughPlatform         6-strut metrology platform (MoM3), GoughDKMSolver for streams
Force distribution: ``pkm_kinematics.distribution``; analyses: ``pkm_kinematics.analysis``.
"""

import importlib

from .errors import (ConfigError, DistributionError, FieldError, JointLimitError, KinematicsError, ParameterError,
                     SingularityError, UnreachablePoseError)

# The package's names, each imported from its module when first asked for (PEP 562):
# ``import pkm_kinematics.errors`` (every package's error classes) loads no model and
# no compiled kernel
_LAZY = {"MachineConfig": "config", "config_dir": "config", "load_machine": "config",
         "load_machine_data": "config", "machine_names": "config",
         "GoughDKMResult": "gough", "GoughDKMSolver": "gough", "GoughPlatform": "gough", "mom3_points": "gough",
         "ForwardKinematicsResult": "machine", "RailLeg": "rails", "RailMachine": "rails"}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'pkm_kinematics' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


__all__ = [
    "ConfigError", "DistributionError", "FieldError", "ForwardKinematicsResult",
    "GoughDKMResult", "GoughDKMSolver", "GoughPlatform", "JointLimitError", "KinematicsError",
    "MachineConfig", "ParameterError", "RailLeg", "RailMachine", "SingularityError",
    "UnreachablePoseError", "config_dir", "load_machine", "load_machine_data", "machine_names",
    "mom3_points",
]
