"""The UAV suite's slow missions, begun in the background as the suite begins.

These missions mostly wait out a documented bound (10 to 30 s): started in the background as the
suite begins (those whose tests are selected), they run beside the others, and their tests come
last (`test_uav_waits.py`, the last file of the suite).
"""
from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager

from conformance.uav_harness import (ABORT_SLACK_S, QUERY_WAIT_S, STARTUP_WAIT_S, Misbehaviour, MissionRun, run_mission,
                                     run_stranded)


def stranded_missions(opts, tmp) -> dict[str, MissionRun]:
    """The UAV on a router without a world, with a world that answers world/info nothing, and with one
    that answers garbage: three UAVs at once."""
    bound = {"none": STARTUP_WAIT_S, "silent": QUERY_WAIT_S, "garbage": QUERY_WAIT_S}
    with ThreadPoolExecutor(len(bound)) as pool:
        jobs = {w: pool.submit(run_stranded, opts, w, tmp / f"world-{w}", bound[w] + ABORT_SLACK_S + 5)
                for w in bound}
        return {w: job.result() for w, job in jobs.items()}


ABSENT = 0   # the robot whose token never comes up (an id no count of robots is written with)


def never_up_mission(opts, tmp) -> MissionRun:
    """Robot 0's token never comes up."""
    return run_mission(opts, Misbehaviour(absent=frozenset({ABSENT})), tmp)


def unacked_mission(opts, tmp) -> MissionRun:
    """Robot 0 cannot execute tick 2; robot 1 never hears the repair that follows (every put of it is lost)."""
    return run_mission(opts, Misbehaviour(error_at={0: 2}, deaf_repair=frozenset({1})), tmp)


SLOW = {"stranded": stranded_missions, "never_up": never_up_mission, "unacked": unacked_mission}
_started: dict[str, Future] = {}


@contextmanager
def in_the_background(names: list[str], opts, tmp_path_factory) -> Iterator[None]:
    """The missions `names` of SLOW, running while the suite does; waited for as it ends."""
    pool = ThreadPoolExecutor(max(1, len(names)), thread_name_prefix="slow-mission")
    for name in names:
        # Each mission's directory is made here, on pytest's own thread: its temporary root is made (and,
        # given --basetemp, emptied first) on the first call, which must not race another thread's.
        _started[name] = pool.submit(SLOW[name], opts, tmp_path_factory.mktemp(name))
    try:
        yield
    finally:
        pool.shutdown(wait=True)
        _started.clear()


def slow(name: str, opts, tmp_path_factory):
    """The run of slow mission `name`: the one begun in the background, or (not begun) one run now."""
    job = _started.get(name)
    return job.result() if job is not None else SLOW[name](opts, tmp_path_factory.mktemp(name))
