"""The planners' numba kernels, compiled once per machine by a process of their own.

`python -m uav_agent.planning.build.warm` compiles them into numba's on-disk cache (tens of
seconds on a fresh clone; about a second when they are cached already: it then only
loads them). `uav-robots run` starts it at once on a cold cache, and so does the UAV
agent when nobody did, so that the compile runs during takeoff and survey in another
process: numba holds the GIL while it compiles, and a compile on a thread of the agent
stalled its perception and flight for as long.

One compile at a time per cache: the compiling process holds the cache's lock
(`compile/lock.py`) from before it starts. Which kernels it compiles, and which of them
say the cache is warm, every planner's row in `registry.py` tells.

Nothing here imports numba until the process compiles: the launcher asks `is_warm()` on every run.
"""
from __future__ import annotations

import argparse
import importlib
import os
import signal
import subprocess
import sys
import time

from ..compile.cache import built, cache_dir, cached
from ..compile.lock import kernel_lock, lock_path, try_lock
from ..registry import DEFAULT_PLANNER, DISTANCE_KERNELS, SPECS, spec
from .child import child_env

# One kernel per family `warm_up` compiles, (module, function): the cache is warm when each has
# an index written after its source file last changed.
MARKERS = tuple(tuple(k.rsplit(".", 1)) for k in (*DISTANCE_KERNELS, *(k for s in SPECS for k in s.kernels)))

# Below the mission, always: what it shares the cores with while the vehicle climbs and surveys
# is the mission's own work (a fresh clone's 450 survey took 9.5-10.3 s beside a compile at the
# mission's priority, 7.5 s beside a niced one), and when a plan waits for it nothing else runs.
NICE = 10


def is_warm() -> bool:
    """True when the kernels the default planner needs are all in numba's cache. A source
    directory numba cannot write to (numba then caches elsewhere) always reads as cold: the
    warm process then only loads the kernels, which costs about a second."""
    aot = built() and os.environ.get("UAV_ROBOTS_KERNELS", "") != "jit"   # compile/jit.py's switch
    return aot or all(cached(m, f) for m, f in MARKERS)


COMPILE_TIMEOUT_S = 900.0


def warm_up(planner: str = DEFAULT_PLANNER, connectivity: int = 4) -> float:
    """Compile the planners' numba kernels (or load them from the on-disk cache) on tiny instances.

    This module's process calls this to compile them on a fresh machine while the UAV takes
    off, and the UAV on a background thread to load them from the cache, so that no
    mission pays either inside its plan phase.
    Every fast kernel is loaded, whatever the planner: lacam is every other
    planner's fallback. On a cold cache a second process compiles LaCAM's search
    while this one compiles the prioritized planner: numba holds the GIL while it
    compiles, so only a process uses the second core (about 45 s -> 28 s here).
    """
    import numpy as np

    from protocol.process import die_with_parent

    from ..compile.jit import AHEAD_OF_TIME
    from ..pipeline import plan_mission

    default = spec(DEFAULT_PLANNER)
    warm_up_fast_planners = getattr(importlib.import_module(f"uav_agent.planning.{default.module}"), default.warm_up)
    t = time.perf_counter()
    aside = None
    if not AHEAD_OF_TIME and not cached(*default.kernels[0].rsplit(".", 1)):
        code = (f"from uav_agent.planning.{default.module} import {default.warm_up}; "
                f"{default.warm_up}(parts=('search', 'pibt'))")
        env = child_env()
        aside = subprocess.Popen([sys.executable, "-c", code], env=env, stdin=subprocess.DEVNULL,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, preexec_fn=die_with_parent)
    try:
        warm_up_fast_planners(parts=("guides",))
        if aside is not None:
            aside.wait(timeout=COMPILE_TIMEOUT_S)
        warm_up_fast_planners(parts=("guides", "search", "pibt"))
        free = np.ones((6, 6), dtype=bool)
        # the mission's planner, and every planner with kernels to warm (prioritized planning and
        # PIBT, compiled above as the default's parts, then only load)
        for name in dict.fromkeys([planner, *(s.name for s in SPECS if s.kernels)]):
            plan_mission(free, [(0, 0), (5, 5)], [(5, 5), (0, 0)], planner=name, connectivity=connectivity,
                         time_limit=600.0, fallback=True)
    finally:
        if aside is not None and aside.poll() is None:
            aside.kill()
            aside.wait()
    return time.perf_counter() - t


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
        if not try_lock(fd, wait=False):
            return None       # another process compiles them: its cache will do
        env = child_env()

        def child_setup() -> None:
            die_with_parent()
            os.setpgid(0, 0)        # a group of its own with its helper compiler: `stop` ends both at once
            os.nice(NICE)

        # the lock belongs to the open file, which the child shares: it holds it until it exits
        return subprocess.Popen([sys.executable, "-m", "uav_agent.planning.build.warm", "--locked-fd", str(fd),
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
    p = argparse.ArgumentParser(prog="python -m uav_agent.planning.build.warm",
                                description="Compile the planners' numba kernels into numba's cache (or load them).")
    p.add_argument("--planner", help="the planner the mission will use (default: the default planner)")
    p.add_argument("--connectivity", type=int, choices=(4, 8), default=4)
    p.add_argument("--locked-fd", type=int, help="an inherited descriptor of the lock file, already locked")
    args = p.parse_args(argv)
    # SIGTERM (the launcher stopping) unwinds, so that warm_up's `finally` stops its second compiler
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))

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
