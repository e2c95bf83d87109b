"""Where numba caches the planning kernels, and the name of the sources they are compiled from.

numba caches a kernel beside its source file (or under NUMBA_CACHE_DIR, in a directory named
after the source's directory): the kernels of `mapf/` and of `paper/` have a cache each. The
sources stamp and the ahead-of-time builds live in this wing's own cache directory, which
no planner's kernels share.

Nothing here imports numba: the launcher asks whether the kernels are warm on every run.
"""
from __future__ import annotations

import hashlib
import os
import platform
import re
import sys
from pathlib import Path

# numba names a cache after os.path.abspath of the source file, not its resolved path
COMPILE_DIR = Path(os.path.abspath(__file__)).parent
PLANNING_DIR = COMPILE_DIR.parent

# a module defines kernels when it imports the kernels' decorator (`from ..compile.jit import njit`)
_DEFINES_KERNELS = re.compile(rb"^from [.\w]*\bjit import [^\n]*\bnjit\b", re.M)


def cache_dir(package: Path = COMPILE_DIR) -> Path:
    """Where numba caches the kernels of the modules in the directory `package`: its in-tree rule,
    or NUMBA_CACHE_DIR's. The default, this wing's, holds the sources stamp and the builds."""
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        # numba's _CacheLocator.get_suitable_cache_subpath
        return Path(given) / f"{package.name}_{hashlib.sha1(str(package).encode()).hexdigest()}"
    return package / "__pycache__"


def kernel_sources() -> list[Path]:
    """The modules a build or numba's cache is compiled from: every one that imports the kernels'
    decorator, and the decorator's and the clock's own."""
    own = (COMPILE_DIR / "jit.py", COMPILE_DIR / "clock.py")
    return [p for p in sorted(PLANNING_DIR.rglob("*.py"))
            if p in own or _DEFINES_KERNELS.search(p.read_bytes())]


def kernel_cache_dirs() -> list[Path]:
    """numba's cache directory of every directory with kernels."""
    return [cache_dir(d) for d in sorted({p.parent for p in kernel_sources()})]


def source_of(module: str) -> Path:
    """The file of `module`, named under uav_agent.planning (`mapf.lacam`)."""
    return PLANNING_DIR.joinpath(*module.split(".")).with_suffix(".py")


def cached(module: str, function: str) -> bool:
    """True when numba has a cache index for `module.function` newer than its source
    (`module` under uav_agent.planning: `mapf.lacam`, `_search`)."""
    source = source_of(module)
    try:
        mtime = source.stat().st_mtime
        return any(p.stat().st_mtime >= mtime for p in cache_dir(source.parent).glob(f"{source.stem}.{function}-*.nbi"))
    except OSError:
        return False


def _cpu_flags() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return next((line for line in f if line.startswith("flags")), "")
    except OSError:
        return ""


_NAME: list[str] = []


def build_name() -> str:
    """Names an ahead-of-time build (`build/aot.py`), and the sources numba's cache holds: every
    module with kernels (numba's cache only checks a kernel's own file), Python, NumPy and the
    CPU it was compiled for."""
    if _NAME:
        return _NAME[0]
    import numpy as np
    h = hashlib.sha256()
    for p in kernel_sources():
        h.update(p.relative_to(PLANNING_DIR).as_posix().encode())
        h.update(p.read_bytes())
    h.update(f"{sys.version}|{np.__version__}|{platform.machine()}|{_cpu_flags()}".encode())
    _NAME.append(f"kernels_{h.hexdigest()[:16]}")
    return _NAME[0]


def build_dir() -> Path:
    """Where the ahead-of-time builds live: beside numba's caches of the same kernels."""
    return cache_dir() / "aot"


def built() -> bool:
    """True when the sources as they are have an ahead-of-time build (not loading it)."""
    return sys.platform.startswith("linux") and (build_dir() / f"{build_name()}.json").is_file()
