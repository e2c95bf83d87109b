"""How the planning kernels are compiled: ahead of time when a build is there, else numba's JIT.

Every kernel module decorates its kernels with this `njit`. What it returns is decided once,
when the first kernel module is imported:

- **ahead-of-time** (`build/aot.py` built the kernels for this source, this Python and this NumPy):
  each kernel is a `Kernel` that calls the build's compiled function for its argument types.
  The process then never imports numba, whose import, compiler set-up and cached kernels'
  loading were 0.6-0.7 s of a 1.1 s `uav-robots plan` (50 robots on the 450 warehouse).
  Argument types the build has not seen fall back to numba's JIT for that kernel (logged).
- **JIT**: `numba.njit`, with numba's on-disk cache (`build/warm.py` fills it on a fresh machine).
  `UAV_ROBOTS_KERNELS=jit` forces it.
- **interpreted** (`NUMBA_DISABLE_JIT=1`, with or without a build; `build/interpreted.py`'s child): the
  kernels run as plain Python, but for the distance fields (SciPy, the same numbers).
- **record** (`UAV_ROBOTS_KERNELS=record`, with `NUMBA_DISABLE_JIT=1`; `build/aot.py`'s own): the
  kernels run interpreted and every call from Python notes its argument types, which are
  the signatures the build compiles.
"""
from __future__ import annotations

import os
import sys
import threading
import time
from typing import Any, Callable

from .prebuilt import Kernel, kind, load_build

MODE_ENV = "UAV_ROBOTS_KERNELS"
LINUX = sys.platform.startswith("linux")


def _array_maths_without_blas() -> None:
    """numba's array maths asks at import whether SciPy's BLAS is there, and asking imports
    `scipy.linalg`: 0.17-0.23 s of every process that loads a kernel. The answer only picks
    how `np.correlate`/`np.convolve` compute inner products (no kernel calls them); `np.dot`
    and `np.linalg` look for the BLAS again when a kernel using them compiles."""
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        return
    sys.modules["scipy.linalg"] = None  # type: ignore[assignment]  # importing it fails
    try:
        import numba.np.arraymath  # noqa: F401
    except ImportError:   # a numba that moved it: only the saving is lost, numba asks when it needs to
        pass
    finally:
        del sys.modules["scipy.linalg"]


def _jit_monotonic():
    import numba
    if numba.config.DISABLE_JIT:
        return time.perf_counter
    if LINUX:
        from .clock import monotonic as clock
        return clock

    @numba.njit(cache=True)
    def clock() -> float:
        with numba.objmode(t="float64"):
            t = time.perf_counter()
        return t
    return clock


def _enable_jit():
    """numba, ready to compile kernels beside (or instead of) the ahead-of-time build."""
    global monotonic
    import numba
    if not numba.config.DISABLE_JIT:
        from .stale import drop_stale_cache
        drop_stale_cache()
    _array_maths_without_blas()
    monotonic = _jit_monotonic()
    if _BUILD is not None:
        from .prebuilt import jit_twins_for_numba
        jit_twins_for_numba()
    return numba


class _Depth(threading.local):
    n = 0


_depth = _Depth()
RECORDED: dict[tuple[str, Any], tuple] = {}


class _Recorder:
    """Record mode: runs the kernel as Python and notes the argument types of calls from Python."""

    def __init__(self, py_func: Callable):
        self.py_func = py_func
        self.name = f"{py_func.__module__}.{py_func.__qualname__}"

    def __call__(self, *args):
        if _depth.n == 0:
            key = (self.name, tuple([kind(a) for a in args]))
            if key not in RECORDED:
                import numba
                RECORDED[key] = tuple(numba.typeof(a) for a in args)
        _depth.n += 1
        try:
            return self.py_func(*args)
        finally:
            _depth.n -= 1


def _decorator(make: Callable[[Callable, dict], Any]):
    def njit(*args, **options):
        if args and callable(args[0]):
            return make(args[0], options)
        return lambda f: make(f, options)
    return njit


MODE = os.environ.get(MODE_ENV, "")
# numba's own switch wins over a build: `build/interpreted.py`'s child is asked for plain Python (a
# build's plan there would not show what a fresh clone's first run does), and so is a user who sets it
_DISABLED = os.environ.get("NUMBA_DISABLE_JIT", "0").strip() not in ("", "0")
_BUILD = None if MODE in ("jit", "record") or _DISABLED else load_build(LINUX)
monotonic: Callable[[], float]
if MODE == "record":
    monotonic = time.perf_counter
    njit = _decorator(lambda f, options: _Recorder(f))
elif _BUILD is not None:
    MODE = "aot"
    monotonic = time.perf_counter        # the build calls clock.monotonic; the JIT swaps it in
    njit = _decorator(lambda f, options: Kernel(f, options, _BUILD.get(f"{f.__module__}.{f.__qualname__}", {}),
                                                      _enable_jit))
else:
    _numba = _enable_jit()
    # NUMBA_DISABLE_JIT=1 (interpreted.py's child): the decorated kernels run as written
    MODE = "interpreted" if _numba.config.DISABLE_JIT else "jit"
    njit = _numba.njit

AHEAD_OF_TIME = MODE == "aot"
# Interpreted, a kernel that visits every cell of a large grid takes seconds: the few that do
# have a NumPy or SciPy twin that gives the same numbers (mapf/distances.py).
INTERPRETED = MODE == "interpreted"
