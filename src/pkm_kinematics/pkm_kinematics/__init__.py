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

from .config import MachineConfig, config_dir, load_machine, load_machine_data, machine_names
from .errors import (ConfigError, DistributionError, JointLimitError, KinematicsError,
                     SingularityError, UnreachablePoseError)
from .gough import GoughDKMResult, GoughDKMSolver, GoughPlatform, mom3_points
from .planar import ForwardKinematicsResult
from .rails import RailLeg, RailMachine

__all__ = [
    "ConfigError", "DistributionError", "ForwardKinematicsResult",
    "GoughDKMResult", "GoughDKMSolver", "GoughPlatform", "JointLimitError", "KinematicsError",
    "MachineConfig", "RailLeg", "RailMachine", "SingularityError",
    "UnreachablePoseError", "config_dir", "load_machine", "load_machine_data", "machine_names",
    "mom3_points",
]
