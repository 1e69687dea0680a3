"""Errors raised by the kinematics core.

Every error names what was wrong (the field, the leg, the limit) so that a node can
report it verbatim and a user can fix the input. All derive from ``ValueError``:
bad input is refused before anything moves.
"""


_UNSET = object()


class FieldError(ValueError):
    """A value refused by the name of its field (a controller setting, a scenario's or
    a node's parameter): ``name``, and ``detail``, what is wrong with it. Made by
    ``out_of_range`` it carries what is ``allowed`` and what it ``got``, and says
    "must be <allowed>, got <got>". ``str()``: "<name>: <detail>". A caller that
    reports it under another name (a node's ``parameter 'x'``) reads the fields,
    never the text."""

    def __init__(self, name: str, detail: str, allowed: str | None = None, got=_UNSET):
        self.name, self.detail, self.allowed = name, detail, allowed
        self.got = None if got is _UNSET else got
        super().__init__(f"{name}: {detail}")

    @classmethod
    def out_of_range(cls, name: str, allowed: str, got) -> "FieldError":
        return cls(name, f"must be {allowed}, got {got!r}", allowed, got)

    def __reduce__(self):
        # pickled with its fields (a Dask worker's error reaches the client, a process
        # pool's its parent); the default pickles args only, which __init__ cannot take
        return _rebuilt, (type(self), self.args, self.name, self.detail, self.allowed, self.got)


def _rebuilt(cls, args, name, detail, allowed, got):
    error = cls.__new__(cls)
    error.args, error.name, error.detail, error.allowed, error.got = args, name, detail, allowed, got
    return error


class ParameterError(FieldError):
    """A node's or a scenario's parameter refused: missing, of the wrong type or out of
    its range. ``str()``: "parameter '<name>': <detail>" (as a ROS user reads it)."""

    def __init__(self, name: str, detail: str, allowed: str | None = None, got=_UNSET):
        super().__init__(name, detail, allowed, got)
        self.args = (f"parameter '{name}': {detail}",)

    def __str__(self) -> str:
        return self.args[0]


class KinematicsError(ValueError):
    """Base class of every error of the kinematics core."""


class ConfigError(FieldError, KinematicsError):
    """A machine configuration field is missing, mistyped or out of range.

    ``field`` (its ``name``) is the dotted path of the offending field
    (``legs[2].link_length``); ``detail`` what is wrong with it.
    """

    def __init__(self, field: str, message: str):
        super().__init__(field, message)

    @property
    def field(self) -> str:
        return self.name


class UnreachablePoseError(KinematicsError):
    """A requested pose cannot be assembled (a leg cannot reach its platform point)."""


class SingularityError(KinematicsError):
    """A configuration where a Jacobian is singular or unbounded (serial or parallel
    singularity, degenerate geometry): the requested quantity does not exist there."""


class JointLimitError(KinematicsError):
    """A joint position is outside the configured range."""


class DistributionError(KinematicsError):
    """A force distribution cannot produce the requested wrench (e.g. singular Jacobian)."""
