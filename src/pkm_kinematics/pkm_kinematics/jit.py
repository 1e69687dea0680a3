"""Compiled per-cycle kernels: ``kernel`` = numba's ``njit(cache=True)``.

The control loop runs the same few formulas 1-2 thousand times a second (the
encoder FK of ARCHI, J_h of the Gough platform, the force distribution). In
CPython each costs 10-30 us of interpreter overhead on 4-6 element loops; compiled,
1-3 us. A kernel is written in the subset of Python numba compiles (floats, ints,
numpy arrays, tuples; no Python objects, errors returned as codes that the calling
method turns into exceptions naming the field), so it is still plain Python: without
numba (``PKM_NO_JIT=1``, or numba not installed) ``kernel`` returns the function
unchanged and everything runs interpreted, with the same results.

The machine code is cached next to the module (``__pycache__``), else in numba's
user cache: the first process after an install compiles (~1-3 s per kernel), later
ones load it. Entry points declare their argument types and are compiled when their
module is imported (see ``kernel``).
"""

from __future__ import annotations

import os

try:
    if os.environ.get("PKM_NO_JIT") == "1":
        raise ImportError("PKM_NO_JIT=1")
    from numba import njit as _njit
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
