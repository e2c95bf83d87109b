"""Planning instances run in worker processes (`worker.py`), with hard deadlines: the parent side of
`uav-robots bench paper` and `bench movingai`.

How it measures (so the figures can be trusted and compared):
- Every instance runs in a worker subprocess, one worker per pipeline (paper) or per map (movingai).
  The parent gives each instance a hard deadline (its time limit plus a margin) and kills a stuck
  worker, records a timeout and starts a fresh worker for the instances left; planners also get
  the time limit itself.
- Times are the pipeline's own phases, from the loaded map and scenario to the validated plan
  (distances, assignment, planning, validation, total); the median over repeats is reported.
- By default workers get an empty numba cache directory, so their warm-up is the true cold
  compile; `--warm-cache` uses the normal cache (then the warm-up is a cache load).
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import subprocess
import sys
import tempfile
import threading
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..common.arguments import positive_float
from .common import fmt, median_of
from .worker import Job

REPO = Path(__file__).resolve().parents[2]
PHASES = ("distances", "assignment", "planning", "validation", "total")


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
        self.proc = subprocess.Popen([sys.executable, "-m", "uav_robots.bench.worker", "--worker"],
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


def run_row(o: Outcome) -> dict[str, Any]:
    row: dict[str, Any] = dict(o.job.tags)
    row.update(agents=o.job.agents, requested=o.job.planner, planner=o.planner, assign=o.job.assign,
               connectivity=o.job.connectivity, status=o.status, fell_back=o.fell_back)
    for p in PHASES:
        row[f"{p}_s"] = o.timings.get(p)
    for m in ("sum_of_costs", "lower_bound", "makespan", "soc_over_lb"):
        row[m] = o.metrics.get(m)
    row.update(peak_rss_mb=o.peak_rss_mb, base_rss_mb=o.base_rss_mb, note=o.error)
    return row


def warmup_lines(warmups: list[Warmup]) -> list[str]:
    firsts: dict[str, list[float]] = {}
    seconds: dict[str, list[float]] = {}
    for w in warmups:
        for key, v in w.calls.items():
            name, label = key.rsplit(":", 1)
            (firsts if label == "first" else seconds).setdefault(name, []).append(v)
    return [f"{name}: first call {fmt(median_of(v), 2)} s, second call {fmt(median_of(seconds.get(name, [])), 3)} s"
            for name, v in sorted(firsts.items())]


def progress_bar():
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=Console(stderr=True), transient=True)


def run_all(groups: dict[str, list[Job]], warm_cache: bool, label: str) -> tuple[list[Outcome], list[Warmup]]:
    outcomes: list[Outcome] = []
    warmups: list[Warmup] = []
    total = sum(len(g) for g in groups.values())
    with progress_bar() as progress:
        task = progress.add_task(label, total=total)
        for name, jobs in groups.items():
            progress.update(task, description=f"{label}: {name}")
            o, w = run_group(name, jobs, warm_cache=warm_cache, on_done=lambda _j: progress.advance(task))
            outcomes += o
            warmups += w
    return outcomes, warmups


def planner_name(p: str) -> str:
    from uav_agent.planning.registry import DEFAULT_PLANNER, check_name
    return DEFAULT_PLANNER if p == "default" else check_name(p)


def add_instance_options(q: argparse.ArgumentParser, limit: float) -> None:
    """The options `bench paper` and `bench movingai` share: the instances, their limit and the cache."""
    q.add_argument("--time-limit", type=positive_float, default=limit,
                   help=f"seconds per instance (default {limit:g}); a worker is killed past it plus a margin")
    q.add_argument("--connectivity", type=int, choices=(4, 8), default=4)
    q.add_argument("--data", metavar="DIR",
                   help="a benchmark data directory laid out like scenarios/data/ (default: the data "
                        "shipped with the package; the 10,000-agent scenario needs --data)")
    q.add_argument("--out", default="bench-out", help="directory for the markdown and CSV (default bench-out/)")
    q.add_argument("--cold-cache", dest="warm_cache", action="store_false",
                   help="compile into an empty numba cache, so the warm-up measures the cold compile "
                        "(default: the normal on-disk cache, whose warm-up is a cache load)")
