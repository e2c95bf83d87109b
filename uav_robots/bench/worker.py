"""The planning benchmarks' worker process (`python -m uav_robots.bench.worker --worker`): reads a JSON list
of jobs on stdin, plans each in turn and writes one JSON line per event on stdout.

Numba's first-call cost is paid by a warm-up on a small warehouse before any timed instance and
reported on its own. Peak memory per instance: the worker resets the kernel's peak-RSS mark before
each instance (`/proc/self/clear_refs` = 5) and reads VmHWM after it; this is the whole process's peak
(interpreter, numpy/scipy/numba included: see the baseline column). Where the reset is not available
the figure is the process's peak so far (ru_maxrss), and the table says so.
"""
from __future__ import annotations

import json
import resource
import sys
import time
import traceback
from dataclasses import dataclass, field
from typing import Any

from protocol.errors import UavRobotsError


@dataclass
class Job:
    map: str                       # a map spec `scenarios.maps.resolve_map` reads: a .map file or a name
    scen_path: str
    agents: int
    planner: str
    assign: str
    connectivity: int
    time_limit: float
    tags: dict[str, Any] = field(default_factory=dict)   # what the tables group by
    stop_after_timeout: bool = False   # a timeout at N skips this group's later jobs with >= N robots
    refine_s: float = 0.0              # seconds of refinement after the plan (movingai --refine)


def _vm_hwm_mb() -> float | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _emit(obj: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def _warmup(planners: set[str], assign: str, connectivity: int) -> dict[str, float]:
    """First and second call of each planner on a small warehouse: the first includes numba's JIT."""
    from scenarios.maps import NAMED, place, warehouse
    from uav_agent.planning.portfolio import warm_up as warm_up_fast_planners
    from uav_agent.planning.pipeline import plan_mission

    free = warehouse(**NAMED["warehouse-small"])
    pl = place(free, 4, 0)
    out: dict[str, float] = {"fast-kernels:first": warm_up_fast_planners()}
    for name in sorted(planners):
        for label in ("first", "second"):
            t = time.perf_counter()
            plan_mission(free, pl.starts, pl.goals, planner=name, assign=assign if assign != "none" else "optimal",
                         connectivity=connectivity, time_limit=600.0, fallback=True)
            out[f"{name}:{label}"] = time.perf_counter() - t
    return out


def worker_main() -> int:
    """Read a JSON list of jobs on stdin; write one JSON line per event on stdout."""
    jobs = [Job(**j) for j in json.load(sys.stdin)]
    t = time.perf_counter()
    from protocol.mapfile import read_scen
    from scenarios.benchmarks import load_map
    from uav_agent.planning.mapf.distances import clear_cache
    from uav_agent.planning.pipeline import plan_mission
    imports = time.perf_counter() - t
    if jobs:
        from uav_agent.planning.registry import DEFAULT_PLANNER
        # The default planner too: a failed paper pipeline falls back to it inside a timed run.
        warm = _warmup({j.planner for j in jobs} | {DEFAULT_PLANNER}, jobs[0].assign, jobs[0].connectivity)
        _emit({"event": "warmup", "imports": imports, "calls": warm})
    maps: dict[str, Any] = {}
    can_reset = _reset_peak()
    stop_at: int | None = None
    for i, job in enumerate(jobs):
        if job.stop_after_timeout and stop_at is not None and job.agents >= stop_at:
            _emit({"event": "result", "index": i, "status": "skipped", "error": f"not run: timed out at N={stop_at}"})
            continue
        base = _vm_hwm_mb() if can_reset and _reset_peak() else None
        res: dict[str, Any] = {"event": "result", "index": i}
        clear_cache()  # every instance pays for its own distance tables, repeats included
        t = time.perf_counter()
        try:
            if job.map not in maps:
                maps[job.map] = load_map(job.map)
            free = maps[job.map]
            agents = read_scen(job.scen_path, free, job.agents)
            r = plan_mission(free, [a.start for a in agents], [a.goal for a in agents], planner=job.planner,
                             assign=job.assign, connectivity=job.connectivity, time_limit=job.time_limit,
                             fallback=True, refine_s=job.refine_s)
            res.update(status="ok", planner=r.planner, fell_back=r.fell_back, timings=r.timings,
                       metrics=r.metrics, error="; ".join(r.notes))
        except UavRobotsError as exc:
            timed_out = time.perf_counter() - t >= job.time_limit
            res.update(status="timeout" if timed_out else "fail", error=str(exc))
            if timed_out and job.stop_after_timeout:
                stop_at = job.agents
        except Exception as exc:  # a planner bug must not end the whole benchmark
            traceback.print_exc()
            res.update(status="fail", error=f"internal error: {type(exc).__name__}: {exc}")
        if can_reset:
            res.update(peak_rss_mb=_vm_hwm_mb(), base_rss_mb=base)
        else:
            res.update(peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, base_rss_mb=None)
        _emit(res)
    return 0


if __name__ == "__main__":
    if sys.argv[1:] == ["--worker"]:
        sys.exit(worker_main())
    sys.stderr.write("usage: python -m uav_robots.bench.worker --worker  (jobs as JSON on stdin); "
                     "run benchmarks with `uav-robots bench`\n")
    sys.exit(2)
