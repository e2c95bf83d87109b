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

import ast
import importlib.util
import json
import os
import sys
import threading
import time
from typing import Any, Callable

import numpy as np

from .cache import build_dir, build_name

MODE_ENV = "UAV_ROBOTS_KERNELS"
LINUX = sys.platform.startswith("linux")


def kind(x: Any) -> Any:
    """What a compiled kernel's signature distinguishes in an argument, in plain Python values
    (the same on both sides of a build: `build/aot.py` keys its exports with it)."""
    t = type(x)
    if t is np.ndarray:
        layout = "C" if x.flags.c_contiguous else "F" if x.flags.f_contiguous else "A"
        return (x.dtype.str, x.ndim, layout, bool(x.flags.writeable))
    if t is bool or t is np.bool_:
        return "b"
    if t is int:
        return "i"
    if t is float:
        return "f"
    if isinstance(x, tuple):
        return (t.__name__, *[kind(v) for v in x])
    if isinstance(x, np.generic):
        # numba types a NumPy int64 or float64 scalar as it does the Python value
        return _SCALAR_KIND.get(x.dtype.str, x.dtype.str)
    return t.__name__


_SCALAR_KIND = {"<i8": "i", "<f8": "f"}


def _load_build() -> dict[str, dict] | None:
    """The build for this source: {kernel name: {argument kinds: compiled function}}, or None."""
    if not LINUX:
        return None
    name = build_name()
    try:
        manifest = json.loads((build_dir() / f"{name}.json").read_text())
        table: dict[str, dict] = {}
        for library in manifest["libraries"]:
            module_name = library["file"].split(".", 1)[0]
            spec = importlib.util.spec_from_file_location(module_name, build_dir() / library["file"])
            if spec is None or spec.loader is None:
                return None
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            for kernel, keyed in library["kernels"].items():
                table.setdefault(kernel, {}).update(
                    {ast.literal_eval(key): getattr(module, export) for key, export in keyed})
        return table
    except (OSError, ValueError, KeyError, ImportError, AttributeError, SyntaxError):
        return None      # no build, or an unreadable one: the JIT will do


class Kernel:
    """A kernel of the ahead-of-time build: its compiled function for the argument types the
    build saw, numba's JIT for any other (and when another JIT-compiled kernel calls it)."""

    def __init__(self, py_func: Callable, options: dict, exports: dict):
        self.py_func = py_func
        self.options = options
        self.exports = exports
        self.name = f"{py_func.__module__}.{py_func.__qualname__}"
        self._dispatcher = None

    def __call__(self, *args):
        f = self.exports.get(tuple([kind(a) for a in args]))
        if f is not None:
            return f(*args)
        return self.dispatcher()(*args)

    def dispatcher(self):
        if self._dispatcher is None:
            numba = _enable_jit()
            _warn_once(f"planner kernel {self.name} has no ahead-of-time build for these argument types: "
                       "numba compiles it")
            self._dispatcher = numba.njit(**self.options)(self.py_func)
        return self._dispatcher


_warned: set[str] = set()


def _warn_once(text: str) -> None:
    if text not in _warned:
        _warned.add(text)
        print(f"warning: {text}", file=sys.stderr)


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
        from numba.core import types
        from numba.extending import typeof_impl

        # a JIT-compiled kernel calling an ahead-of-time one calls its JIT twin
        @typeof_impl.register(Kernel)
        def _typeof_kernel(val, c):
            return types.Dispatcher(val.dispatcher())
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
_BUILD = None if MODE in ("jit", "record") or _DISABLED else _load_build()
monotonic: Callable[[], float]
if MODE == "record":
    monotonic = time.perf_counter
    njit = _decorator(lambda f, options: _Recorder(f))
elif _BUILD is not None:
    MODE = "aot"
    monotonic = time.perf_counter        # the build calls clock.monotonic; the JIT swaps it in
    njit = _decorator(lambda f, options: Kernel(f, options, _BUILD.get(f"{f.__module__}.{f.__qualname__}", {})))
else:
    _numba = _enable_jit()
    # NUMBA_DISABLE_JIT=1 (interpreted.py's child): the decorated kernels run as written
    MODE = "interpreted" if _numba.config.DISABLE_JIT else "jit"
    njit = _numba.njit

AHEAD_OF_TIME = MODE == "aot"
# Interpreted, a kernel that visits every cell of a large grid takes seconds: the few that do
# have a NumPy or SciPy twin that gives the same numbers (mapf/distances.py).
INTERPRETED = MODE == "interpreted"
