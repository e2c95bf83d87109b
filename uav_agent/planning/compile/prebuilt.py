"""An ahead-of-time build of the planning kernels (`build/aot.py`), loaded without numba.

Each kernel of the build is a `Kernel`: the build's compiled function for the argument types
it was compiled for, numba's JIT (through `jit.py`) for any other.
"""
from __future__ import annotations

import ast
import importlib.util
import json
import sys
from typing import Any, Callable

import numpy as np

from .cache import build_dir, build_name


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


def load_build(linux: bool) -> dict[str, dict] | None:
    """The build for this source: {kernel name: {argument kinds: compiled function}}, or None."""
    if not linux:
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
    build saw, numba's JIT for any other (and when another JIT-compiled kernel calls it).
    `enable_jit` readies numba beside the build and returns it, the first time a kernel needs it."""

    def __init__(self, py_func: Callable, options: dict, exports: dict, enable_jit: Callable):
        self.py_func = py_func
        self.enable_jit = enable_jit
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
            numba = self.enable_jit()
            _warn_once(f"planner kernel {self.name} has no ahead-of-time build for these argument types: "
                       "numba compiles it")
            self._dispatcher = numba.njit(**self.options)(self.py_func)
        return self._dispatcher


_warned: set[str] = set()


def _warn_once(text: str) -> None:
    if text not in _warned:
        _warned.add(text)
        print(f"warning: {text}", file=sys.stderr)


def jit_twins_for_numba() -> None:
    """Once numba runs beside the build: a JIT-compiled kernel calling an ahead-of-time one calls its JIT twin."""
    from numba.core import types
    from numba.extending import typeof_impl

    @typeof_impl.register(Kernel)
    def _typeof_kernel(val, c):
        return types.Dispatcher(val.dispatcher())
