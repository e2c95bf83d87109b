"""The benchmark: the paper's Table 2 re-run on the 450x450 warehouse, and MovingAI instances.

How it measures (so the figures can be trusted and compared):
- Every instance runs in a worker subprocess (`python -m uav_robots.bench --worker`),
  one worker per pipeline (paper) or per map (movingai). The parent gives each instance a
  hard deadline (its time limit plus a margin) and kills a stuck worker, records a timeout
  and starts a fresh worker for the instances left; planners also get the time limit itself.
- Times are the pipeline's own phases, from the loaded map and scenario to the validated plan
  (distances, assignment, planning, validation, total); the median over repeats is reported.
- Numba's first-call cost is paid by a warm-up on a small warehouse in each worker before
  any timed instance and reported on its own. By default workers get an empty numba cache
  directory, so that warm-up is the true cold compile; `--warm-cache` uses the normal cache
  (then the warm-up is a cache load).
- Peak memory per instance: the worker resets the kernel's peak-RSS mark before each instance
  (`/proc/self/clear_refs` = 5) and reads VmHWM after it; this is the whole process's peak
  (interpreter, numpy/scipy/numba included: see the baseline column). Where the reset is
  not available the figure is the process's peak so far (ru_maxrss), and the table says so.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import queue
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from protocol.errors import UavRobotsError

REPO = Path(__file__).resolve().parents[1]

# The paper's Table 2, seconds (A* failed at 50 within its 3-minute bound).
PAPER_TABLE2: dict[str, dict[int, float | None]] = {
    "paper-astar": {3: 9.549, 5: 16.814, 10: 35.458, 15: 65.271, 25: 135.569, 30: 178.326, 50: None},
    "paper-prm": {3: 5.424, 5: 7.982, 10: 15.136, 15: 20.568, 25: 37.435, 30: 44.283, 50: 75.209},
}
# LaCAM3 (C++) on warehouse-10-20-10-2-1, random-1, from bench-results/reference-solvers.md.
MOVINGAI_REFERENCE = {"warehouse-10-20-10-2-1": {50: 0.12, 100: 0.14, 200: 0.20, 400: 0.54, 1000: 2.43}}

PAPER_SIZES = (3, 5, 10, 15, 25, 30, 50, 100, 250, 500, 1000)
PHASES = ("distances", "assignment", "planning", "validation", "total")


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


@dataclass
class Outcome:
    job: Job
    status: str                    # "ok", "fail", "timeout", "skipped"
    error: str = ""
    planner: str = ""              # the planner that produced the plan (after any fallback)
    fell_back: bool = False
    timings: dict[str, float] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)
    peak_rss_mb: float | None = None
    base_rss_mb: float | None = None


# ---------------------------------------------------------------------------- the worker

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


# ---------------------------------------------------------------------------- the parent

@dataclass
class Warmup:
    group: str
    imports: float
    calls: dict[str, float]


class _Worker:
    """One worker process and a thread turning its stdout into a queue of events."""

    def __init__(self, jobs: list[Job], cache_dir: str | None):
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH", "")]))
        if cache_dir:
            env["NUMBA_CACHE_DIR"] = cache_dir
        self.stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([sys.executable, "-m", "uav_robots.bench", "--worker"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.stderr,
                                     env=env, cwd=str(REPO), text=True)
        self.events: queue.Queue[dict[str, Any] | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        assert self.proc.stdin is not None
        try:
            self.proc.stdin.write(json.dumps([asdict(j) for j in jobs]))
            self.proc.stdin.close()
        except BrokenPipeError:
            pass

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                self.events.put(json.loads(line))
            except json.JSONDecodeError:
                continue
        self.events.put(None)

    def next(self, timeout: float) -> dict[str, Any] | None | str:
        """The next event, None if the worker ended, "timeout" if none came in time."""
        try:
            return self.events.get(timeout=max(timeout, 0.0))
        except queue.Empty:
            return "timeout"

    def stderr_tail(self) -> str:
        self.stderr.seek(0)
        lines = self.stderr.read().decode("utf-8", "replace").strip().splitlines()
        return lines[-1][:200] if lines else ""

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass
        if self.proc.stdout:
            self.proc.stdout.close()
        self.stderr.close()


def run_group(name: str, jobs: list[Job], *, warm_cache: bool, warmup_timeout: float = 900.0,
              on_done: Callable[[Job], None] | None = None) -> tuple[list[Outcome], list[Warmup]]:
    """Run `jobs` in a worker, starting a fresh one after a hard timeout or a crash."""
    outcomes: list[Outcome] = []
    warmups: list[Warmup] = []

    def record(o: Outcome) -> None:
        outcomes.append(o)
        if on_done:
            on_done(o.job)

    pending = list(jobs)
    while pending:
        with tempfile.TemporaryDirectory(prefix="uavr-numba-") as cache:
            w = _Worker(pending, None if warm_cache else cache)
            try:
                ev = w.next(warmup_timeout)
                if not isinstance(ev, dict) or ev.get("event") != "warmup":
                    why = ("warm-up timed out" if ev == "timeout"
                           else f"worker failed in its warm-up: {w.stderr_tail()}")
                    for j in pending:
                        record(Outcome(j, "fail", why))
                    break
                warmups.append(Warmup(name, ev["imports"], ev["calls"]))
                for i, job in enumerate(pending):
                    ev = w.next(job.time_limit + max(30.0, 0.25 * job.time_limit))
                    if isinstance(ev, dict):
                        ev.pop("event", None)
                        ev.pop("index", None)
                        record(Outcome(job, **ev))
                        continue
                    if ev == "timeout":
                        record(Outcome(job, "timeout", f"killed at the hard deadline ({job.time_limit:g} s + margin)"))
                    else:
                        record(Outcome(job, "fail", f"worker crashed: {w.stderr_tail()}"))
                    rest = pending[i + 1:]
                    if ev == "timeout" and job.stop_after_timeout:
                        for j in rest:
                            if j.agents >= job.agents:
                                record(Outcome(j, "skipped", f"not run: timed out at N={job.agents}"))
                        rest = [j for j in rest if j.agents < job.agents]
                    pending = rest
                    break
                else:
                    pending = []
            finally:
                w.close()
    return outcomes, warmups


# ---------------------------------------------------------------------------- tables

def _median(values: Iterable[float]) -> float | None:
    vals = [v for v in values if v is not None]
    return statistics.median(vals) if vals else None


def _fmt(v: float | None, digits: int = 3) -> str:
    if v is None:
        return "-"
    return f"{v:.{digits}f}"


def _markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with path.open("w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=keys)
        wr.writeheader()
        wr.writerows(rows)


def _run_row(o: Outcome) -> dict[str, Any]:
    row: dict[str, Any] = dict(o.job.tags)
    row.update(agents=o.job.agents, requested=o.job.planner, planner=o.planner, assign=o.job.assign,
               connectivity=o.job.connectivity, status=o.status, fell_back=o.fell_back)
    for p in PHASES:
        row[f"{p}_s"] = o.timings.get(p)
    for m in ("sum_of_costs", "lower_bound", "makespan", "soc_over_lb"):
        row[m] = o.metrics.get(m)
    row.update(peak_rss_mb=o.peak_rss_mb, base_rss_mb=o.base_rss_mb, note=o.error)
    return row


def _warmup_lines(warmups: list[Warmup]) -> list[str]:
    firsts: dict[str, list[float]] = {}
    seconds: dict[str, list[float]] = {}
    for w in warmups:
        for key, v in w.calls.items():
            name, label = key.rsplit(":", 1)
            (firsts if label == "first" else seconds).setdefault(name, []).append(v)
    return [f"{name}: first call {_fmt(_median(v), 2)} s, second call {_fmt(_median(seconds.get(name, [])), 3)} s"
            for name, v in sorted(firsts.items())]


def _progress():
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=Console(stderr=True), transient=True)


def _print(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _run_all(groups: dict[str, list[Job]], warm_cache: bool, label: str) -> tuple[list[Outcome], list[Warmup]]:
    outcomes: list[Outcome] = []
    warmups: list[Warmup] = []
    total = sum(len(g) for g in groups.values())
    with _progress() as progress:
        task = progress.add_task(label, total=total)
        for name, jobs in groups.items():
            progress.update(task, description=f"{label}: {name}")
            o, w = run_group(name, jobs, warm_cache=warm_cache, on_done=lambda _j: progress.advance(task))
            outcomes += o
            warmups += w
    return outcomes, warmups


# ---------------------------------------------------------------------------- bench paper

def _sizes(text: str) -> list[int]:
    try:
        sizes = sorted({int(s) for s in text.split(",") if s.strip()})
    except ValueError:
        raise UavRobotsError(f"--sizes {text!r}: give comma-separated integers, e.g. 3,5,10") from None
    if not sizes or sizes[0] < 1:
        raise UavRobotsError(f"--sizes {text!r}: sizes must be at least 1")
    return sizes


def _planner_name(p: str) -> str:
    from uav_agent.planning.registry import DEFAULT_PLANNER, check_name
    return DEFAULT_PLANNER if p == "default" else check_name(p)


def run_paper(args: argparse.Namespace) -> int:
    from scenarios.benchmarks import paper_map_spec, paper_scen
    from uav_agent.planning.assignment import check_mode

    sizes = _sizes(args.sizes)
    pipelines = [p.strip() for p in args.pipelines.split(",") if p.strip()]
    names = {p: _planner_name(p) for p in pipelines}
    check_mode(args.assign)
    if args.repeat < 1 or not args.time_limit > 0:
        raise UavRobotsError("--repeat must be at least 1 and --time-limit positive")
    # Unless --data holds a map, the worker regenerates it and checks it against the published map's hash.
    map_spec, scen_path = paper_map_spec(args.data), paper_scen(1, args.data)
    groups: dict[str, list[Job]] = {}
    skipped_paper = []
    for p in pipelines:
        jobs = []
        for n in sizes:
            if names[p] in ("paper-astar", "paper-prm") and n > args.paper_max:
                skipped_paper.append(n)
                continue
            for r in range(args.repeat):
                jobs.append(Job(map_spec, str(scen_path), n, names[p], args.assign, args.connectivity,
                                args.time_limit, {"pipeline": p, "repeat": r}, stop_after_timeout=True))
        if jobs:
            groups[p] = jobs
    outcomes, warmups = _run_all(groups, args.warm_cache, "bench paper")

    header = ["pipeline", "N", "solved", "total s", "distances", "assignment", "planning", "validation",
              "SoC/LB", "makespan", "peak RSS MB", "paper s", "paper s / ours"]
    rows, summary = [], []
    for p in pipelines:
        for n in sizes:
            runs = [o for o in outcomes if o.job.tags["pipeline"] == p and o.job.agents == n]
            if not runs:
                continue
            ok = [o for o in runs if o.status == "ok"]
            med = {ph: _median(o.timings.get(ph) for o in ok) for ph in PHASES}
            ratio = _median(o.metrics.get("soc_over_lb") for o in ok)
            mk = _median(o.metrics.get("makespan") for o in ok)
            rss = max((o.peak_rss_mb for o in runs if o.peak_rss_mb is not None), default=None)
            paper_key = names[p] if names[p] in PAPER_TABLE2 else "paper-prm"
            paper_s = PAPER_TABLE2[paper_key].get(n)
            paper_txt = ("fail" if n in PAPER_TABLE2[paper_key] and paper_s is None else _fmt(paper_s, 3))
            speed = paper_s / med["total"] if paper_s and med["total"] else None
            label = p if p == names[p] else f"{p} ({names[p]})"
            fb = sum(o.fell_back for o in ok)
            solved = f"{len(ok)}/{len(runs)}" + (f" ({fb} fell back)" if fb else "")
            if not ok:
                solved += f" {runs[0].status}: {runs[0].error[:60]}"
            rows.append([label, str(n), solved, _fmt(med["total"]), _fmt(med["distances"]), _fmt(med["assignment"]),
                         _fmt(med["planning"]), _fmt(med["validation"]), _fmt(ratio, 4), _fmt(mk, 0),
                         _fmt(rss, 0), paper_txt, f"{speed:.0f}x" if speed else "-"])
            summary.append({"pipeline": p, "planner": names[p], "agents": n, "solved": len(ok), "runs": len(runs),
                            "fell_back": fb, **{f"{ph}_s": med[ph] for ph in PHASES}, "soc_over_lb": ratio,
                            "makespan": mk, "peak_rss_mb": rss, "paper_s": paper_s, "speedup": speed})
    notes = [
        f"Instance: first N start-goal pairs of {scen_path.name} on {Path(map_spec).name}, {args.connectivity}-connected; "
        f"goals re-assigned by the pipeline ({args.assign} assignment, true shortest-path distances, for every "
        "pipeline including the paper's); limit "
        f"{args.time_limit:g} s per instance; median of {args.repeat} run(s); times in seconds from the loaded "
        "map to the validated plan, in-process in a warm worker (numba's first call paid before, last note).",
        "paper s: the planning time the paper reports in its Table 2 (A* for paper-astar, PRM for paper-prm and, as "
        "the paper's best, for ours): its machine, its own placements, its boundary; paper s / ours divides it by "
        "our in-process total: only its order of magnitude means anything; not a ratio measured side by side.",
        "SoC/LB: sum of costs / sum of the assigned robots' shortest-path distances.",
        "Peak RSS: the worker process's peak during the instance (interpreter and libraries included).",
    ]
    if skipped_paper:
        notes.append(f"The paper's pipelines were not run above N={args.paper_max} (slow; change with --paper-max).")
    notes.append("Numba first-call cost, paid once per worker before the timed runs ("
                 + ("warm cache" if args.warm_cache else "cold compile, empty cache") + "): "
                 + "; ".join(_warmup_lines(warmups)))
    text = _markdown(header, rows) + "\n\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    _save(args.out, "paper", "# Paper Table 2 re-run (450x450 warehouse)\n\n" + text, summary,
          [_run_row(o) for o in outcomes])
    _print(text)
    return 0


def _save(out: str, stem: str, markdown: str, summary: list[dict[str, Any]], runs: list[dict[str, Any]]) -> None:
    d = Path(out)
    try:
        d.mkdir(parents=True, exist_ok=True)
        (d / f"{stem}.md").write_text(markdown, encoding="utf-8")
        _write_csv(d / f"{stem}.csv", summary)
        _write_csv(d / f"{stem}-runs.csv", runs)
    except OSError as exc:
        raise UavRobotsError(f"cannot write benchmark results to {d}: {exc.strerror or exc}") from None
    _print(f"wrote {d / (stem + '.md')}, {d / (stem + '.csv')}, {d / (stem + '-runs.csv')}")


# ---------------------------------------------------------------------------- bench movingai

def _scens(text: str) -> list[str]:
    """`random-1..5,even-2` -> [random-1, ..., random-5, even-2]."""
    out: list[str] = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        m = re.fullmatch(r"([a-z]+)-(\d+)(?:\.\.(\d+))?", part)
        if not m:
            raise UavRobotsError(f"--scens {part!r}: expected e.g. random-1, random-1..5 or even-3")
        lo, hi = int(m.group(2)), int(m.group(3) or m.group(2))
        out += [f"{m.group(1)}-{k}" for k in range(lo, hi + 1)]
    if not out:
        raise UavRobotsError("--scens: give at least one scenario")
    return out


def run_movingai(args: argparse.Namespace) -> int:
    planner = _planner_name(args.planner)
    agents = _sizes(args.agents)
    scens = _scens(args.scens)
    maps = [m.strip() for m in args.maps.split(",") if m.strip()]
    if not args.time_limit > 0:
        raise UavRobotsError("--time-limit must be positive")
    from scenarios.benchmarks import movingai_map, movingai_scen

    groups: dict[str, list[Job]] = {}
    for m in maps:
        map_path = movingai_map(m, args.data)
        jobs = []
        for n in agents:
            for s in scens:
                scen_path = movingai_scen(m, s, args.data)
                jobs.append(Job(str(map_path), str(scen_path), n, planner, "none", args.connectivity,
                                args.time_limit, {"map": m, "scen": s}, refine_s=args.refine))
        groups[m] = jobs
    outcomes, warmups = _run_all(groups, args.warm_cache, "bench movingai")

    header = ["map", "N", "solved", "median s", "max s", "planning s", "SoC/LB", "makespan", "peak RSS MB",
              "LaCAM3 (C++) s"]
    rows, summary = [], []
    for m in maps:
        for n in agents:
            runs = [o for o in outcomes if o.job.tags["map"] == m and o.job.agents == n]
            ok = [o for o in runs if o.status == "ok"]
            med = _median(o.timings.get("total") for o in ok)
            worst = max((o.timings["total"] for o in ok), default=None)
            plan_s = _median(o.timings.get("planning") for o in ok)
            ratio = _median(o.metrics.get("soc_over_lb") for o in ok)
            mk = _median(o.metrics.get("makespan") for o in ok)
            rss = max((o.peak_rss_mb for o in runs if o.peak_rss_mb is not None), default=None)
            ref = MOVINGAI_REFERENCE.get(m, {}).get(n)
            fb = sum(o.fell_back for o in ok)
            solved = f"{len(ok)}/{len(runs)}" + (f" ({fb} fell back)" if fb else "")
            rows.append([m, str(n), solved, _fmt(med), _fmt(worst), _fmt(plan_s), _fmt(ratio, 4), _fmt(mk, 0),
                         _fmt(rss, 0), _fmt(ref, 2)])
            summary.append({"map": m, "agents": n, "planner": planner, "solved": len(ok), "runs": len(runs),
                            "fell_back": fb, "median_total_s": med, "max_total_s": worst, "median_planning_s": plan_s,
                            "soc_over_lb": ratio, "makespan": mk, "peak_rss_mb": rss, "reference_lacam3_s": ref})
    notes = [
        f"Planner {planner}" + (f" then up to {args.refine:g} s of refinement (MAPF-LNS, `--refine`)"
                                if args.refine else "")
        + f", {args.connectivity}-connected, the scenario's own start-goal pairs (no assignment), "
        f"scenarios {', '.join(scens)}; limit {args.time_limit:g} s per instance; times in seconds from the "
        "loaded map to the validated plan.",
        "SoC/LB: sum of costs / sum of the robots' shortest-path distances; LaCAM3 (C++) s: the whole process of "
        "its binary on random-1 only, from bench-results/reference-solvers.md (the team's figures, not this run): "
        "not like for like with our in-process medians.",
        "Peak RSS: the worker process's peak over the instance (interpreter and libraries included).",
        "Numba first-call cost, paid once per worker before the timed runs ("
        + ("warm cache" if args.warm_cache else "cold compile, empty cache") + "): "
        + "; ".join(_warmup_lines(warmups)),
    ]
    failures = [o for o in outcomes if o.status != "ok"]
    for o in failures[:10]:
        notes.append(f"{o.job.tags['map']} {o.job.tags['scen']} N={o.job.agents}: {o.status}: {o.error[:120]}")
    text = _markdown(header, rows) + "\n\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    _save(args.out, "movingai", "# MovingAI benchmark\n\n" + text, summary, [_run_row(o) for o in outcomes])
    _print(text)
    return 0


if __name__ == "__main__":
    if sys.argv[1:] == ["--worker"]:
        sys.exit(worker_main())
    sys.stderr.write("usage: python -m uav_robots.bench --worker  (jobs as JSON on stdin); "
                     "run benchmarks with `uav-robots bench`\n")
    sys.exit(2)
