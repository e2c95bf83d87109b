"""The planners' numba kernels, compiled once per machine by a process of their own.

`python -m uav_agent.planning.warm` compiles them into numba's on-disk cache (tens of
seconds on a fresh clone; about a second when they are cached already: it then only
loads them). `uav-robots run` starts it at once on a cold cache, and so does the UAV
agent when nobody did, so that the compile runs during takeoff and survey in another
process: numba holds the GIL while it compiles, and a compile on a thread of the agent
stalled its perception and flight for as long.

One compile at a time per cache: the compiling process holds an exclusive lock (flock)
on a file named after the cache directory, and whoever needs the kernels takes the same
lock first, so that it waits and then loads them instead of compiling them a second
time. Numba writes each cache file atomically, but two processes that compile the same
kernels waste the second core, and each rewrites the whole index of a function: two
writers can drop each other's entries, or give two signatures the same data file.

Nothing here imports numba: the launcher asks `is_warm()` on every run.
"""
from __future__ import annotations

import argparse
import errno
import fcntl
import hashlib
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

# numba names a cache after os.path.abspath of the source file, not its resolved path
PACKAGE_DIR = Path(os.path.abspath(__file__)).parent

# One kernel per family `pipeline.warm_up` compiles: the cache is warm when each has an index
# written after its source file last changed.
MARKERS = (("distances", "_bfs_rows"), ("prioritized", "_plan_in_order"), ("lacam", "_search"), ("pibt", "_run"),
           ("scatter", "_scatter"))

# Below the mission, always: what it shares the cores with while the vehicle climbs and surveys
# is the mission's own work (a fresh clone's 450 survey took 9.5-10.3 s beside a compile at the
# mission's priority, 7.5 s beside a niced one), and when a plan waits for it nothing else runs.
NICE = 10


def child_env(**extra: str) -> dict[str, str]:
    """The environment of a Python child that imports this package (compiler, interpreted
    planner, build): ours, `extra`, and the package's root first on its path."""
    root = str(PACKAGE_DIR.parents[1])
    return {**os.environ, **extra, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}


def cache_dir() -> Path:
    """Where numba caches this package's kernels: its in-tree rule, or NUMBA_CACHE_DIR's."""
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        # numba's _CacheLocator.get_suitable_cache_subpath
        return Path(given) / f"{PACKAGE_DIR.name}_{hashlib.sha1(str(PACKAGE_DIR).encode()).hexdigest()}"
    return PACKAGE_DIR / "__pycache__"


def cached(module: str, function: str) -> bool:
    """True when numba has a cache index for `module.function` newer than its source."""
    try:
        source = (PACKAGE_DIR / f"{module}.py").stat().st_mtime
        return any(p.stat().st_mtime >= source for p in cache_dir().glob(f"{module}.{function}-*.nbi"))
    except OSError:
        return False


def is_warm() -> bool:
    """True when the kernels the default planner needs are all in numba's cache. A source
    directory numba cannot write to (numba then caches elsewhere) always reads as cold: the
    warm process then only loads the kernels, which costs about a second."""
    aot = built() and os.environ.get("UAV_ROBOTS_KERNELS", "") != "jit"   # jit.py's switch
    return aot or all(cached(m, f) for m, f in MARKERS)


def _cpu_flags() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return next((line for line in f if line.startswith("flags")), "")
    except OSError:
        return ""


_NAME: list[str] = []


def kernel_sources() -> list[Path]:
    """The modules a build or numba's cache is compiled from: every one that imports the kernels'
    decorator, and the decorator's and the clock's own."""
    return [p for p in sorted(PACKAGE_DIR.glob("*.py"))
            if p.name in ("jit.py", "clock.py") or re.search(rb"^from \.jit import [^\n]*\bnjit\b", p.read_bytes(), re.M)]


def build_name() -> str:
    """Names an ahead-of-time build (`aot.py`), and the sources numba's cache holds: every
    module with kernels (numba's cache only checks a kernel's own file), Python, NumPy and the
    CPU it was compiled for."""
    if _NAME:
        return _NAME[0]
    import numpy as np
    h = hashlib.sha256()
    for p in kernel_sources():
        h.update(p.name.encode())
        h.update(p.read_bytes())
    h.update(f"{sys.version}|{np.__version__}|{platform.machine()}|{_cpu_flags()}".encode())
    _NAME.append(f"kernels_{h.hexdigest()[:16]}")
    return _NAME[0]


def drop_stale_cache() -> None:
    """Empties numba's cache of these kernels when any planning source changed since it was filled.

    numba checks a cached kernel against its own file only, yet a kernel holds the code of the
    helpers it calls from other files: after an edit of `grid_kernels.py` alone, LaCAM's cached
    search kept the old helpers (here: an object-mode clock whose module had lost `time`, a
    NameError at run time; in general, silently old behaviour). A stamp beside the cache names
    the sources it was compiled from."""
    d = cache_dir()
    stamp = d / "sources.stamp"
    name = build_name()
    try:
        if stamp.read_text() == name:
            return
    except OSError:
        pass
    with kernel_lock(what="stamp"):
        try:
            if stamp.read_text() == name:
                return      # another process has just done it
        except OSError:
            pass
        for old in list(d.glob("*.nbi")) + list(d.glob("*.nbc")):
            old.unlink(missing_ok=True)
        try:
            d.mkdir(parents=True, exist_ok=True)
            tmp = d / f".sources.stamp.{os.getpid()}"
            tmp.write_text(name)
            os.replace(tmp, stamp)
        except OSError:
            pass    # a cache directory numba cannot write to either: it then caches elsewhere


def build_dir() -> Path:
    """Where the ahead-of-time builds live: beside numba's cache of the same kernels."""
    return cache_dir() / "aot"


def built() -> bool:
    """True when the sources as they are have an ahead-of-time build (not loading it)."""
    return sys.platform.startswith("linux") and (build_dir() / f"{build_name()}.json").is_file()


def lock_path(what: str = "kernels") -> Path:
    key = hashlib.blake2b(str(cache_dir()).encode(), digest_size=8).hexdigest()
    return Path(tempfile.gettempdir()) / f"uav-robots-{what}-{key}.lock"


def _try_lock(fd: int, wait: bool) -> bool:
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
    except OSError as exc:
        if exc.errno in (errno.EAGAIN, errno.EACCES):
            return False
        raise
    return True


@contextmanager
def kernel_lock(wait: bool = True, what: str = "kernels") -> Iterator[bool]:
    """Holds the cache's compile lock (waiting for a compile in another process when `wait`);
    yields False when `wait` is False and another process holds it. `what="aot"`: the lock of
    the ahead-of-time build, which nobody waits for."""
    fd = os.open(lock_path(what), os.O_RDWR | os.O_CREAT, 0o666)
    try:
        yield _try_lock(fd, wait)
    finally:
        os.close(fd)  # releases the lock


def busy() -> bool:
    """True while another process compiles (or loads) the kernels."""
    with kernel_lock(wait=False) as mine:
        return not mine


def start(planner: str | None = None, connectivity: int = 4) -> subprocess.Popen | None:
    """On a cold cache with nobody compiling: a process that compiles the kernels (niced), which
    holds the lock from before it starts (no window in which another process could take it);
    otherwise None. The process dies with its parent, or by `stop`; what it
    compiled by then stays cached."""
    if is_warm():
        return None
    from protocol.process import die_with_parent

    fd = os.open(lock_path(), os.O_RDWR | os.O_CREAT, 0o666)
    try:
        if not _try_lock(fd, wait=False):
            return None       # another process compiles them: its cache will do
        env = child_env()

        def child_setup() -> None:
            die_with_parent()
            os.setpgid(0, 0)        # a group of its own with its helper compiler: `stop` ends both at once
            os.nice(NICE)

        # the lock belongs to the open file, which the child shares: it holds it until it exits
        return subprocess.Popen([sys.executable, "-m", "uav_agent.planning.warm", "--locked-fd", str(fd),
                                 "--connectivity", str(connectivity), *(["--planner", planner] if planner else [])],
                                env=env, pass_fds=(fd,), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, preexec_fn=child_setup)
    finally:
        os.close(fd)


def stop(compiler: subprocess.Popen) -> None:
    """Ends a compile `start` began, with its helper process: SIGKILL to the group, which numba's
    cache survives (it writes each file under a temporary name, then renames it)."""
    if compiler.poll() is None:
        try:
            os.killpg(compiler.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    compiler.wait()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m uav_agent.planning.warm",
                                description="Compile the planners' numba kernels into numba's cache (or load them).")
    p.add_argument("--planner", help="the planner the mission will use (default: the default planner)")
    p.add_argument("--connectivity", type=int, choices=(4, 8), default=4)
    p.add_argument("--locked-fd", type=int, help="an inherited descriptor of the lock file, already locked")
    args = p.parse_args(argv)
    # SIGTERM (the launcher stopping) unwinds, so that warm_up's `finally` stops its second compiler
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))

    from .pipeline import warm_up
    from .registry import DEFAULT_PLANNER

    planner = args.planner or DEFAULT_PLANNER
    if args.locked_fd is not None:
        seconds = warm_up(planner, args.connectivity)
    else:
        with kernel_lock():
            seconds = warm_up(planner, args.connectivity)
    print(f"planner kernels ready in {seconds:.1f} s ({cache_dir()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
