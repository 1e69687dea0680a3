"""Compiled per-cycle kernels: ``kernel`` = numba's ``njit(cache=True)``.

The control loop runs the same few formulas 1-2 thousand times a second (the
encoder FK of ARCHI, J_h of the Gough platform, the force distribution). In
CPython each costs 10-30 us of interpreter overhead on 4-6 element loops; compiled,
1-3 us. A kernel is written in the subset of Python numba compiles (floats, ints,
numpy arrays, tuples; no Python objects, errors returned as codes that the calling
method turns into exceptions naming the field), so it is still plain Python: without
numba (``PKM_NO_JIT=1``, or numba not installed) ``kernel`` returns the function
unchanged and everything runs interpreted, with the same results up to rounding
(LAPACK's inverse of J_h differs in the last bits between numpy and numba).

Entry points declare their argument types and are compiled, or loaded from the
cache, when their module is imported (see ``kernel``): the first import after an
install or an edit compiles (~10 s), later ones load the machine code (~1 s).
numba's cache notices edits to a kernel's own file only, not to the kernels it
calls in other files; the cache directory is therefore keyed by a hash of the
sources of every file that may hold a kernel (this package's, and those of the
packages in ``KERNEL_PACKAGES`` that import this module), so that a kernel may call
kernels of any other file: ``$NUMBA_CACHE_DIR`` or ``~/.cache/pkm``, then
``numba-<hash>``. Old directories there can be deleted at any time.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
from pathlib import Path

# the packages outside this one with kernels (a file there holds kernels if it imports this module)
KERNEL_PACKAGES = ("pkm_common", "pkm_sim_hw", "pkm_gough_sensor", "pkm_controller", "pkm_recording")


def _kernel_sources():
    """(name, source) of each file that may hold a kernel, in a fixed order."""
    for path in sorted(Path(__file__).parent.glob("*.py")):
        yield "pkm_kinematics/" + path.name, path.read_bytes()
    for package in KERNEL_PACKAGES:
        try:
            spec = importlib.util.find_spec(package)      # found, not imported
        except (ImportError, ValueError):                 # ValueError: imported without a spec (a stub)
            spec = None
        for location in (spec.submodule_search_locations or []) if spec else []:
            for path in sorted(Path(location).glob("*.py")):
                try:
                    source = path.read_bytes()
                except OSError:                           # removed meanwhile (a rebuild)
                    continue
                if b"pkm_kinematics.jit import" in source:
                    yield f"{package}/{path.name}", source


def _cache_dir() -> str:
    digest = hashlib.sha256()
    for name, source in _kernel_sources():
        digest.update(name.encode() + b"\0" + source)
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "pkm")
    return os.path.join(base, "numba-" + digest.hexdigest()[:16])


try:
    if os.environ.get("PKM_NO_JIT") == "1":
        raise ImportError("PKM_NO_JIT=1")
    import numba
    from numba import njit as _njit
    numba.config.CACHE_DIR = _cache_dir()
    COMPILED = True
except ImportError:                    # interpreted fallback: same code, same results
    _njit = None
    COMPILED = False


def kernel(signature: str | None = None):
    """Decorator: compile the function with numba (no Python objects, cached on disk).

    With ``signature`` (the argument types, e.g. ``"(float64[:, :], float64)"``) it is
    compiled, or loaded from the cache, when its module is imported: never in the
    first control cycle, and a call with other types raises TypeError instead of
    compiling inside the loop. Without, it is compiled for the types of its callers
    (for helpers called only by other kernels). The interpreted function stays
    available as ``.py_func``."""
    def decorate(function):
        if _njit is None:
            function.py_func = function
            return function
        if signature is None:
            return _njit(cache=True, nogil=True)(function)
        return _njit(signature, cache=True, nogil=True)(function)
    return decorate


# "1": every direct_call checks its arguments' types against the declared signature
# (TypeError naming the kernel and the argument), for the tests (tests/kinematics/test_jit.py)
CHECK_DIRECT_CALLS_ENV = "PKM_CHECK_DIRECT_CALLS"
CHECKED: dict[str, int] = {}          # checked calls per kernel (in that mode)


def direct_call(compiled):
    """The machine code of a kernel compiled for its declared signature, to be called
    without numba's dispatcher, which types every argument on each call (about half of
    a 9-14-argument kernel's call when its work is a warm-started solve). Only for a
    per-call path whose arguments the caller makes itself, with exactly the declared
    types: no conversion is done, and an argument of another type is undefined
    behaviour (``PKM_CHECK_DIRECT_CALLS=1`` checks each call). Interpreted
    (``PKM_NO_JIT=1``): the function itself."""
    overloads = getattr(compiled, "overloads", None)
    if not overloads:
        return compiled
    signature, overload = next(iter(overloads.items()))      # the first: the declared signature
    if os.environ.get(CHECK_DIRECT_CALLS_ENV) == "1":
        return _checked_call(compiled.py_func.__qualname__, signature, overload.entry_point)
    return overload.entry_point


def _accepts(declared, actual) -> bool:
    """Whether the entry point compiled for ``declared`` (a numba type) takes a value
    of numba type ``actual`` as it is: the same type, or an array of the same dtype and
    dimensions where any layout is declared."""
    from numba.core import types
    if isinstance(declared, types.Array):
        return (isinstance(actual, types.Array) and actual.dtype == declared.dtype and actual.ndim == declared.ndim
                and declared.layout in ("A", actual.layout))
    if isinstance(declared, types.BaseTuple):
        return (isinstance(actual, types.BaseTuple) and len(actual) == len(declared)
                and all(_accepts(d, a) for d, a in zip(declared, actual)))
    return declared == actual


def _checked_call(name: str, signature: tuple, entry):
    def call(*args):
        if len(args) != len(signature):
            raise TypeError(f"{name}: {len(args)} arguments, declared {len(signature)}")
        for i, (declared, value) in enumerate(zip(signature, args)):
            actual = numba.typeof(value)
            if not _accepts(declared, actual):
                raise TypeError(f"{name}: argument {i} is {actual}, declared {declared}")
        CHECKED[name] = CHECKED.get(name, 0) + 1
        return entry(*args)
    return call
