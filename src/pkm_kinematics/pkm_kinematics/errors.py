"""Errors raised by the kinematics core.

Every error names what was wrong (the field, the leg, the limit) so that a node can
report it verbatim and a user can fix the input. All derive from ``ValueError``:
bad input is refused before anything moves.
"""


class KinematicsError(ValueError):
    """Base class of every error of the kinematics core."""


class ConfigError(KinematicsError):
    """A machine configuration field is missing, mistyped or out of range.

    ``field`` is the dotted path of the offending field (``legs[2].link_length``).
    """

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"{field}: {message}")


class UnreachablePoseError(KinematicsError):
    """A requested pose cannot be assembled (a leg cannot reach its platform point)."""


class SingularityError(KinematicsError):
    """A configuration where a Jacobian is singular or unbounded (serial or parallel
    singularity, degenerate geometry): the requested quantity does not exist there."""


class JointLimitError(KinematicsError):
    """A joint position is outside the configured range."""


class DistributionError(KinematicsError):
    """A force distribution cannot produce the requested wrench (e.g. singular Jacobian)."""
