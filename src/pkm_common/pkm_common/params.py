"""Typed ROS parameters with ranges, declared and read in one call.

Each ``declare_*`` declares the parameter with a ParameterDescriptor (type, range as
FloatingPointRange / IntegerRange, description, ``additional_constraints`` text, so
``ros2 param describe`` shows the allowed values), reads the effective value (default
or override from the command line / YAML) and checks what a descriptor cannot say
(open bounds, string choices, list length, per-element ranges).

Any bad value raises ParameterError naming the parameter and the allowed range:
``parameter 'noise_std_m': must be in [0, inf) m, got -1.0``. Nodes read their
parameters once at start, so by default they are declared read-only: a later
``ros2 param set`` is refused instead of silently having no effect.

An integer override of a float parameter (``noise_std_m: 0`` in YAML) is accepted
as the float it means; rclpy alone would refuse it as a type mismatch.
"""

from __future__ import annotations

import math

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

from pkm_kinematics.errors import ParameterError

INT64_MIN, INT64_MAX = -2**63, 2**63 - 1


class _Range:
    """A range as ParameterValues reads it (FloatingPointRange's, IntegerRange's fields)."""

    __slots__ = ("from_value", "to_value")

    def __init__(self, from_value, to_value):
        self.from_value, self.to_value = from_value, to_value


class _Descriptor:
    """What ParameterValues reads of a declaration's descriptor: rclpy's message checks
    every field it is given (~4 us a declaration, ~100 of them in a direct run's
    set-up), and only a node shows it (``ros2 param describe``)."""

    __slots__ = ("type", "dynamic_typing", "floating_point_range", "integer_range")

    def __init__(self, kind: int, dynamic_typing: bool, floating_point_range: list, integer_range: list):
        self.type, self.dynamic_typing = kind, dynamic_typing
        self.floating_point_range, self.integer_range = floating_point_range, integer_range


def _descriptor(node, kind: int, description: str, read_only: bool, allowed: str, *, dynamic_typing: bool = False,
                float_range: tuple | None = None, int_range: tuple | None = None):
    """The descriptor of a declaration on ``node``: rclpy's ParameterDescriptor for a
    node, a plain record of the fields it checks for ParameterValues."""
    if isinstance(node, ParameterValues):
        return _Descriptor(kind, dynamic_typing, [_Range(*float_range)] if float_range else [],
                           [_Range(*int_range)] if int_range else [])
    return ParameterDescriptor(
        type=kind, description=description, read_only=read_only, additional_constraints=allowed,
        dynamic_typing=dynamic_typing,
        floating_point_range=[FloatingPointRange(from_value=float_range[0], to_value=float_range[1], step=0.0)]
        if float_range else [],
        integer_range=[IntegerRange(from_value=int_range[0], to_value=int_range[1], step=0)] if int_range else [])


# ParameterError (pkm_kinematics.errors, a FieldError): a parameter value is missing,
# of the wrong type or out of its range; raised here, and by the pure cores that name
# a node's parameters


def _fmt(v) -> str:
    return f'{v:g}' if isinstance(v, float) else str(v)


def _interval(lo, hi, lo_open=False, hi_open=False, unit='') -> str:
    left = '(' if lo_open or lo == -math.inf else '['
    right = ')' if hi_open or hi == math.inf else ']'
    return f'{left}{_fmt(lo)}, {_fmt(hi)}{right}' + (f' {unit}' if unit else '')


def _override(node, name):
    """The value given on the command line / in YAML, if any (for messages and the
    int -> float coercion; rclpy keeps it in a private dict, read defensively)."""
    overrides = getattr(node, '_parameter_overrides', None) or {}
    param = overrides.get(name)
    return None if param is None else param.value


def _refused(exc: Exception) -> bool:
    """rclpy's ParameterException (a value of the wrong type or out of the declared
    range) or ParameterValues' own, told by class name: this module stays importable
    without rclpy (the pure core's declarations, ParameterValues)."""
    return any(c.__name__ == 'ParameterException' for c in type(exc).__mro__)


def _declare(node, name, default, descriptor: ParameterDescriptor, allowed: str):
    try:
        return node.declare_parameter(name, default, descriptor).value
    except Exception as exc:
        if not _refused(exc):
            raise
        given = _override(node, name)
        shown = f'got {given!r}' if given is not None else f'rclpy: {exc}'
        raise ParameterError(name, f'must be {allowed}, {shown}') from None


def declare_float(node, name: str, default: float, lo: float = -math.inf, hi: float = math.inf,
                  description: str = '', *, lo_open: bool = False, hi_open: bool = False,
                  unit: str = '', read_only: bool = True) -> float:
    """A finite double in [lo, hi] (``lo_open``/``hi_open`` exclude a bound)."""
    allowed = f'a number in {_interval(lo, hi, lo_open, hi_open, unit)}'
    given = _override(node, name)
    if isinstance(given, int) and not isinstance(given, bool):
        # integer written for a float parameter: take it as the float
        default = float(given)
        ignore_override = True
    else:
        default = float(default)
        ignore_override = False
    descriptor = _descriptor(node, ParameterType.PARAMETER_DOUBLE, description, read_only, allowed,
                             float_range=(float(lo), float(hi)))
    if ignore_override:
        value = _declare_ignoring_override(node, name, default, descriptor, allowed)
    else:
        value = _declare(node, name, default, descriptor, allowed)
    if not isinstance(value, float) or not math.isfinite(value) or value < lo or value > hi \
            or (lo_open and value == lo) or (hi_open and value == hi):
        raise ParameterError(name, f'must be {allowed}, got {value!r}')
    return value


def _declare_ignoring_override(node, name, value, descriptor, allowed):
    try:
        return node.declare_parameter(name, value, descriptor, ignore_override=True).value
    except Exception as exc:
        if not _refused(exc):
            raise
        raise ParameterError(name, f'must be {allowed}, got {value!r}') from None


def declare_int(node, name: str, default: int, lo: int = INT64_MIN, hi: int = INT64_MAX,
                description: str = '', *, read_only: bool = True) -> int:
    """An integer in [lo, hi]."""
    allowed = f'an integer in [{lo}, {hi}]'
    descriptor = _descriptor(node, ParameterType.PARAMETER_INTEGER, description, read_only, allowed,
                             int_range=(int(lo), int(hi)))
    value = _declare(node, name, int(default), descriptor, allowed)
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        raise ParameterError(name, f'must be {allowed}, got {value!r}')
    return value


def declare_str(node, name: str, default: str, description: str = '', *, choices=None,
                allow_empty: bool = False, read_only: bool = True) -> str:
    """A string, one of ``choices`` if given."""
    choices = None if choices is None else [str(c) for c in choices]
    allowed = f'one of {choices}' if choices is not None else (
        'a string' if allow_empty else 'a non-empty string')
    descriptor = _descriptor(node, ParameterType.PARAMETER_STRING, description, read_only, allowed)
    value = _declare(node, name, str(default), descriptor, allowed)
    if not isinstance(value, str) or (choices is not None and value not in choices) \
            or (not allow_empty and not value):
        raise ParameterError(name, f'must be {allowed}, got {value!r}')
    return value


def declare_bool(node, name: str, default: bool, description: str = '', *,
                 read_only: bool = True) -> bool:
    """true or false."""
    allowed = 'true or false'
    descriptor = _descriptor(node, ParameterType.PARAMETER_BOOL, description, read_only, allowed)
    value = _declare(node, name, bool(default), descriptor, allowed)
    if not isinstance(value, bool):
        raise ParameterError(name, f'must be {allowed}, got {value!r}')
    return value


def declare_float_list(node, name: str, default, description: str = '', *,
                       length: int | None = None, lo: float = -math.inf, hi: float = math.inf,
                       unit: str = '', read_only: bool = True) -> list[float]:
    """A list of finite doubles, each in [lo, hi], of ``length`` items if given.

    Integers in an override list (``[1, 2]`` is an integer array to ROS) are taken as
    floats. An empty default cannot carry a type in ROS 2 (``[]`` is a byte array to
    rclpy), so such a parameter is declared with dynamic typing and checked here.
    """
    count = f'{length} numbers' if length is not None else 'numbers'
    allowed = f'a list of {count}, each in {_interval(lo, hi, unit=unit)}'
    default = [float(v) for v in default]
    given = _override(node, name)
    descriptor = _descriptor(node, ParameterType.PARAMETER_DOUBLE_ARRAY, description, read_only, allowed,
                             dynamic_typing=not default)
    if default and given is not None and not isinstance(given, str) and len(given) and all(
            isinstance(v, int) and not isinstance(v, bool) for v in given):
        value = _declare_ignoring_override(node, name, [float(v) for v in given], descriptor, allowed)
    else:
        value = _declare(node, name, default, descriptor, allowed)
    if value is None:              # an empty override of a dynamically typed list
        value = []
    if isinstance(value, (str, bytes, bool, int, float)):
        raise ParameterError(name, f'must be {allowed}, got {value!r}')
    value = list(value)
    if length is not None and len(value) != length:
        raise ParameterError(name, f'must be {allowed}, got {len(value)} values: {value!r}')
    out = []
    for k, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            raise ParameterError(name, f'must be {allowed}, got {v!r} at index {k}')
        out.append(float(v))
    return out


__all__ = ['ParameterError', 'ParameterValues', 'declare_bool', 'declare_float', 'declare_float_list',
           'declare_int', 'declare_like', 'declare_str']


class _Value:
    __slots__ = ('value',)

    def __init__(self, value):
        self.value = value


class ParameterException(ValueError):
    """A value ParameterValues refuses as rclpy would (its type, its range)."""


def _parameter_type(value) -> int:
    """The ParameterType of a Python value, by rclpy's rules (Parameter.Type.from_parameter_value)."""
    for kind, test in ((ParameterType.PARAMETER_BOOL, lambda v: isinstance(v, bool)),
                       (ParameterType.PARAMETER_INTEGER, lambda v: isinstance(v, int)),
                       (ParameterType.PARAMETER_DOUBLE, lambda v: isinstance(v, float)),
                       (ParameterType.PARAMETER_STRING, lambda v: isinstance(v, str))):
        if test(value):
            return kind
    if isinstance(value, (list, tuple)):
        for kind, item in ((ParameterType.PARAMETER_BYTE_ARRAY, bytes), (ParameterType.PARAMETER_BOOL_ARRAY, bool),
                           (ParameterType.PARAMETER_INTEGER_ARRAY, int), (ParameterType.PARAMETER_DOUBLE_ARRAY, float),
                           (ParameterType.PARAMETER_STRING_ARRAY, str)):
            if all(isinstance(v, item) for v in value):
                return kind
    return ParameterType.PARAMETER_NOT_SET


class ParameterValues:
    """A node's parameters without a node: what the ``declare_*`` functions need of
    one, over a dict of overrides (a run's params/<node>.yaml as pkm_bringup.scenario
    makes it), so that a core built from a node's declarations is built the same way
    without rclpy's node (the direct engine, pkm_bringup.direct). rclpy's own checks
    are kept: an override of another type than the descriptor's is refused, and a
    value outside the descriptor's range."""

    def __init__(self, values: dict):
        self._parameter_overrides = {name: _Value(value) for name, value in values.items()}
        self.declared: dict = {}

    def declare_parameter(self, name: str, default, descriptor: ParameterDescriptor, ignore_override: bool = False):
        given = self._parameter_overrides.get(name)
        value = default if ignore_override or given is None else given.value
        kind = _parameter_type(value)
        if not descriptor.dynamic_typing and kind != descriptor.type:
            raise ParameterException(f'wrong type for parameter {name!r}')
        for ranges in (descriptor.floating_point_range, descriptor.integer_range):
            if ranges and not ranges[0].from_value <= value <= ranges[0].to_value:
                raise ParameterException(f'parameter {name!r} out of range')
        self.declared[name] = value
        return _Value(value)

    def has_parameter(self, name: str) -> bool:
        return name in self.declared

    def get_parameter(self, name: str):
        return _Value(self.declared[name])


def declare_like(node, name: str, default):
    """Declare ``name`` typed like ``default`` (bool, int >= 0, float, str (empty
    allowed), or a tuple of floats (a list, empty allowed)) and return its value; the
    value only if it is already declared."""
    if node.has_parameter(name):
        return node.get_parameter(name).value
    if isinstance(default, tuple):
        return tuple(declare_float_list(node, name, list(default)))
    if isinstance(default, bool):
        return declare_bool(node, name, default)
    if isinstance(default, int):
        return declare_int(node, name, default, 0)
    if isinstance(default, float):
        return declare_float(node, name, default)
    return declare_str(node, name, default, allow_empty=True)
