"""`uav-robots bench mission`: whole `uav-robots run` commands in a row, each run's phases from its report.

The mission's speed targets (the survey's in issue 8, the whole mission's in issue 10) are
figures of whole runs on a noisy machine, where one run says little. This runs the command
as a user does, `--runs` times in a row, each into a fresh output directory (and with
`--cold-cache` into an empty numba cache each: a new machine's first run), and tabulates
each run from what it wrote: survey + perceive (report.json's timings), command start to the
summary line and to exit (timed here, around the process), and what the survey needed beyond
its images (closer looks, retakes: report.json's events). A run that fails is a row with its
exit code and last line; its directory keeps its logs.

    uav-robots bench mission --runs 30 --map warehouse-450 --robots 50 --out bench-out
    uav-robots bench mission --runs 10 --map default --target-s 0 --out bench-out
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

from protocol.errors import UavRobotsError

from .common import print_now

RUN_TIMEOUT_S = 900.0      # a 1,000-robot mission on a loaded 2-core machine stays well inside
SUMMARY_PREFIX = "mission "  # the summary's first line: "mission COMPLETED: ..."


@dataclass(frozen=True)
class Run:
    run: int
    exit: int
    outcome: str
    survey_perceive_s: float | None   # report.json: survey + perceive
    summary_s: float | None           # command start -> the summary line on stdout
    wall_s: float                     # command start -> exit
    closer_looks: int
    retakes: int
    collisions: int | None
    verified: str                     # robots verified on their goals / robots
    out: str
    error: str = ""
    build_s: float | None = None      # `uav-robots build` into the run's empty cache first (--build)


def run_once(i: int, args: argparse.Namespace, out: Path, extra: list[str], name: str) -> Run:
    """One whole `uav-robots run` into `out`, timed around the process; `name`: `out` as the table shows it."""
    cmd = [sys.executable, "-m", "uav_robots", "run", "--quiet", "--out", str(out)]
    if args.map != "default":
        cmd += ["--map", args.map]
    if args.robots:
        cmd += ["--robots", str(args.robots)]
    cmd += extra   # last: what the user adds overrides the bench's own
    env = dict(os.environ)
    with tempfile.TemporaryDirectory(prefix="uavr-bench-numba-") as cache:
        if args.cold_cache:
            env["NUMBA_CACHE_DIR"] = cache
        build_s = None
        if args.build:
            began = time.perf_counter()
            built = subprocess.run([sys.executable, "-m", "uav_robots", "build"], env=env, capture_output=True,
                                   text=True, timeout=RUN_TIMEOUT_S)
            build_s = round(time.perf_counter() - began, 2)
            if built.returncode != 0:
                last = (built.stderr.strip().splitlines() or ["no output"])[-1]
                return Run(i, built.returncode, "build failed", None, None, 0.0, 0, 0, None, "", name,
                           f"uav-robots build: {last}", build_s)
        summary: list[float] = []
        lines: list[str] = []
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)

        def read() -> None:
            for line in proc.stdout:
                if line.startswith(SUMMARY_PREFIX) and not summary:
                    summary.append(time.perf_counter() - start)
                lines.append(line.rstrip("\n"))

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            code = proc.wait(timeout=RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait()
            lines.append(f"killed after {RUN_TIMEOUT_S:g} s")
        wall = time.perf_counter() - start
        reader.join(timeout=10.0)
    (out / "bench-stdout.txt").parent.mkdir(parents=True, exist_ok=True)
    (out / "bench-stdout.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return replace(_from_report(i, code, out, name, summary[0] if summary else None, wall, lines), build_s=build_s)


def _from_report(i: int, code: int, out: Path, name: str, summary_s: float | None, wall: float,
                 lines: list[str]) -> Run:
    last = next((ln.strip() for ln in reversed(lines) if ln.strip()), "no output")
    try:
        report = json.loads((out / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        return Run(i, code, "no report", None, summary_s, round(wall, 2), 0, 0, None, "", name,
                   f"report.json unreadable ({exc}); last line: {last}")
    timings = report.get("timings") or {}
    survey = timings.get("survey")
    kinds = [e.get("kind") for e in report.get("events") or []]
    verified = report.get("verified") or {}
    robots = len(verified) if isinstance(verified, dict) else 0
    return Run(i, code, str(report.get("outcome", "")),
               None if survey is None else round(survey + timings.get("perceive", 0.0), 2),
               None if summary_s is None else round(summary_s, 2), round(wall, 2),
               kinds.count("closer-look"), kinds.count("retake"), report.get("collisions"),
               f"{sum(1 for v in verified.values() if v)}/{robots}", name,
               "" if code == 0 else last)


def _stats(values: list[float]) -> str:
    if not values:
        return "-"
    return f"{min(values):.2f}-{max(values):.2f} s, median {statistics.median(values):.2f} s"


def markdown(runs: list[Run], args: argparse.Namespace, command: str) -> str:
    ok = [r for r in runs if r.exit == 0]
    sp = [r.survey_perceive_s for r in ok if r.survey_perceive_s is not None]
    lines = [f"# `uav-robots run` {len(runs)} times in a row", "",
             f"Command (whole process, timed around it): `{command}`"
             + (", each run with an empty `NUMBA_CACHE_DIR` (a new machine's first run)" if args.cold_cache else
                ", numba's cache as it is (warm after the first run)")
             + (", after `uav-robots build` into that cache (timed apart, not in the run's figures)"
                if args.build else "") + ".", "",
             f"- completed (exit 0): {len(ok)} of {len(runs)}",
             f"- survey + perceive: {_stats(sp)}"
             + (f"; within {args.target_s:g} s: {sum(1 for v in sp if v <= args.target_s)} of {len(sp)}"
                if args.target_s > 0 else ""),
             f"- command start to summary line: {_stats([r.summary_s for r in ok if r.summary_s is not None])}",
             f"- command start to exit: {_stats([r.wall_s for r in ok])}",
             f"- closer looks: {sum(r.closer_looks for r in runs)}, retakes: {sum(r.retakes for r in runs)}, "
             f"collisions: {sum(r.collisions or 0 for r in runs)}", "",
             "| run | exit | outcome | verified | survey + perceive | to summary | to exit | closer looks | retakes "
             "| collisions |" + (" build first |" if args.build else ""),
             "|---|---|---|---|---|---|---|---|---|---|" + ("---|" if args.build else "")]
    for r in runs:
        def s(v: float | None) -> str:
            return "-" if v is None else f"{v:.2f} s"
        lines.append(f"| {r.run} | {r.exit} | {r.outcome} | {r.verified} | {s(r.survey_perceive_s)} | "
                     f"{s(r.summary_s)} | {s(r.wall_s)} | {r.closer_looks} | {r.retakes} | {r.collisions} |"
                     + (f" {s(r.build_s)} |" if args.build else ""))
    failed = [r for r in runs if r.error]
    if failed:
        lines += ["", "Failed runs (their logs are in their directories, under the results' directory):", ""]
        lines += [f"- run {r.run} ({r.out}): {r.error}" for r in failed]
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    if args.runs < 1:
        raise UavRobotsError(f"--runs must be at least 1, got {args.runs}")
    try:
        extra = shlex.split(args.run_args)
    except ValueError as exc:
        raise UavRobotsError(f"--run-args {args.run_args!r}: {exc}") from None
    out = Path(args.out)
    try:
        (out / "mission-runs").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UavRobotsError(f"cannot write benchmark results to {out}: {exc.strerror or exc}") from None
    shown = ["uav-robots", "run", "--quiet"] + (["--map", args.map] if args.map != "default" else []) \
        + (["--robots", str(args.robots)] if args.robots else []) + ["--out", "DIR"] + extra
    command = " ".join(shlex.quote(part) for part in shown)
    runs: list[Run] = []
    for i in range(1, args.runs + 1):
        name = f"mission-runs/run{i:02d}"
        r = run_once(i, args, out / name, extra, name)
        runs.append(r)
        print_now(f"run {i}/{args.runs}: exit {r.exit}, survey + perceive "
               f"{'-' if r.survey_perceive_s is None else f'{r.survey_perceive_s:.2f} s'}, "
               f"to summary {'-' if r.summary_s is None else f'{r.summary_s:.2f} s'}, to exit {r.wall_s:.2f} s"
               + (f" ({r.error})" if r.error else ""))
    text = markdown(runs, args, command)
    (out / "mission.md").write_text(text, encoding="utf-8")
    (out / "mission.json").write_text(json.dumps({"command": command, "cold_cache": args.cold_cache,
                                                  "build": args.build,
                                                  "runs": [asdict(r) for r in runs]}, indent=1) + "\n",
                                      encoding="utf-8")
    print_now(f"wrote {out / 'mission.md'}, {out / 'mission.json'} (each run's outputs and logs in {out / 'mission-runs'})")
    return 0 if all(r.exit == 0 for r in runs) else 1


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("mission", help="whole `uav-robots run` commands in a row: survey, summary and exit times",
                       description="Run the whole mission command several times in a row and tabulate each run's "
                                   "survey + perceive, time to the summary and to exit, closer looks and retakes.")
    p.add_argument("--runs", type=int, default=10, help="missions in a row (default 10)")
    p.add_argument("--map", default="warehouse-450", help="the run's --map, or 'default' for its own (default "
                                                           "warehouse-450)")
    p.add_argument("--robots", type=int, default=50, help="the run's --robots; 0 for its default (default 50)")
    p.add_argument("--run-args", default="", metavar="ARGS", help="more arguments for each run, e.g. "
                                                                  "\"--camera realistic,blur_sigma=2\"")
    p.add_argument("--target-s", type=float, default=8.0,
                   help="count the runs whose survey + perceive is within this (default 8, issue 8's target; 0: none)")
    p.add_argument("--cold-cache", action="store_true",
                   help="each run with an empty numba cache: a new machine's first run")
    p.add_argument("--build", action="store_true",
                   help="run `uav-robots build` before each run (into its empty cache with --cold-cache), timed "
                        "apart: a new machine's first run after the one-time build")
    p.add_argument("--out", default="bench-out", help="directory for mission.md, mission.json and the runs' "
                                                      "outputs (default bench-out/)")
    return p
