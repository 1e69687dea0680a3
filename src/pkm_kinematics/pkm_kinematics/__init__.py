"""pkm_kinematics: the pure numpy/scipy kinematics core of the PKM controller.

No rclpy import anywhere in this package: nodes call it, tests call it directly.

Models (one class per machine family, built from ``config/machines/*.yaml``):
  PlanarMachine         n >= 3 PRR legs (ARCHI, Sliding Star)
  TranslationalMachine  3 prismatic + parallelogram legs (MoM3 linear Delta, Orthoglide)
  GoughPlatform         6-strut metrology platform (MoM3), GoughDKMSolver for streams
Force distribution: ``pkm_kinematics.distribution``; analyses: ``pkm_kinematics.analysis``.
"""

from .config import MachineConfig, config_dir, load_machine, load_machine_data, machine_names
from .errors import (ConfigError, DistributionError, JointLimitError, KinematicsError,
                     SingularityError, UnreachablePoseError)
from .gough import GoughDKMResult, GoughDKMSolver, GoughPlatform, mom3_points
from .planar import ForwardKinematicsResult, PlanarLeg, PlanarMachine
from .translational import TranslationalLeg, TranslationalMachine

__all__ = [
    "ConfigError", "DistributionError", "ForwardKinematicsResult",
    "GoughDKMResult", "GoughDKMSolver", "GoughPlatform", "JointLimitError", "KinematicsError",
    "MachineConfig", "PlanarLeg", "SingularityError", "PlanarMachine", "TranslationalLeg", "TranslationalMachine",
    "UnreachablePoseError", "config_dir", "load_machine", "load_machine_data", "machine_names",
    "mom3_points",
]
