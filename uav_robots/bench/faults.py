"""`uav-robots bench faults`: whole missions with faults injected, each ended as it should?

Issue 29's measure of a fleet that survives its parts: every single fault, and every
combination that leaves a robot able to finish, ends COMPLETED (exit 0) or DEGRADED (exit 3),
with no collision and no false claim. This runs a catalogue of fault scenarios (stalls that
come back, crashes, liars, a drive that keeps skidding, slips of 5-10 %, all of them at once on
30-80 robots, several seeds) as whole `uav-robots run` commands, one after the other, and
tabulates each from its report.json: the exit code, the outcome, robots verified, collisions and
safety stops (the world's record), repairs, the robots out of the plan and why. A scenario
passes when it exits 0 or 3, its report agrees with its exit code, the world counted no
collision, and every robot the UAV calls verified stands on a goal in the world's record.

    uav-robots bench faults --out bench-out           # the 36 scenarios, about 20 minutes here
    uav-robots bench faults --quick --out bench-out   # one of each kind, about 5 minutes
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

RUN_TIMEOUT_S = 900.0
TICK_TIMEOUT = ["--tick-timeout", "3"]   # a silent robot is stalled after 3 s, not 10: shorter runs, same logic
ALL_AT_ONCE = ["--fault", "crash:3@5", "--fault", "stall:5@3:20", "--fault", "slip:0.05", "--fault", "liar:2"]


def scenarios(quick: bool = False) -> list[tuple[str, list[str]]]:
    """(name, run arguments) of each scenario; `quick`: the first of each kind."""
    kinds: list[list[tuple[str, list[str]]]] = [
        [(f"stall-{k}", ["--robots", "20", *TICK_TIMEOUT, "--fault", f"stall:5@3:{k}"]) for k in (1, 5, 20)],
        [(f"crash-s{s}", ["--robots", "20", "--seed", str(s), "--fault", "crash:3@4"]) for s in (0, 1)],
        [(f"liar-s{s}", ["--robots", "20", "--seed", str(s), *TICK_TIMEOUT, "--fault", "liar:2"]) for s in (0, 1)],
        [(f"skid-s{s}", ["--robots", "20", "--seed", str(s), "--fault", "skid:9@2"]) for s in (0, 1, 2)],
        [(f"slip5-30-s{s}", ["--robots", "30", "--seed", str(s), "--fault", "slip:0.05"]) for s in range(5)],
        [(f"slip10-20-s{s}", ["--robots", "20", "--seed", str(s), "--fault", "slip:0.10"]) for s in (5, 6)],
        [(f"all-30-s{s}", ["--robots", "30", "--seed", str(s), *TICK_TIMEOUT, *ALL_AT_ONCE]) for s in range(5)],
        [(f"all-50-s{s}", ["--robots", "50", "--seed", str(s), *TICK_TIMEOUT, *ALL_AT_ONCE]) for s in range(4)],
        [(f"skid-slip-s{s}", ["--robots", "30", "--seed", str(s), "--fault", "skid:7@3", "--fault", "slip:0.05"])
         for s in (0, 1)],
        [(f"crash2-stall-s{s}", ["--robots", "30", "--seed", str(s), "--fault", "crash:1@2", "--fault", "crash:8@6",
                                 "--fault", "stall:12@4:8"]) for s in (0, 1)],
        [(f"stalls-s{s}", ["--robots", "30", "--seed", str(s), *TICK_TIMEOUT, "--fault", "stall:4@2:5", "--fault",
                           "stall:9@3:10", "--fault", "stall:14@5:2"]) for s in (0, 1)],
        [(f"pools-80-s{s}", ["--robots", "80", "--seed", str(s), *TICK_TIMEOUT, "--fault", "crash:3@5", "--fault",
                             "slip:0.03", "--fault", "stall:40@3:6"]) for s in (0, 1)],
        [("8conn", ["--robots", "20", "--connectivity", "8", *TICK_TIMEOUT, "--fault", "slip:0.05", "--fault",
                    "stall:5@3:5"])],
        [("two-skids", ["--robots", "30", "--seed", "3", "--fault", "skid:2@2", "--fault", "skid:11@4"])],
    ]
    return [kind[0] for kind in kinds] if quick else [s for kind in kinds for s in kind]


@dataclass(frozen=True)
class Row:
    name: str
    args: str
    exit: int
    outcome: str
    verified: str
    collisions: int | None
    safety_stops: int | None
    replans: int | None
    out_of_plan: dict
    seconds: float
    passed: bool
    why: str = ""


def judge(name: str, args: list[str], code: int, report: dict | None, details: dict | None, seconds: float) -> Row:
    """One scenario's row: passed when it ended COMPLETED or DEGRADED with what its report says true."""
    if report is None:
        return Row(name, " ".join(args), code, "no report", "-", None, None, None, {}, seconds, False,
                   "no report.json")
    verified = report.get("verified", {})
    outcome = report.get("outcome", "?")
    why = []
    if code not in (0, 3):
        why.append(f"exit {code}")
    if (code, outcome) not in ((0, "completed"), (3, "degraded")):
        why.append(f"exit {code} with outcome {outcome}")
    if report.get("collisions") != 0:
        why.append(f"{report.get('collisions')} collisions")
    goals = {tuple(g) for g in (report.get("truth") or {}).get("goals", [])}
    executed = (details or {}).get("executed", {})
    false = [r for r, ok in verified.items() if ok and (not executed.get(r) or tuple(executed[r][-1]) not in goals)]
    if false:
        why.append(f"robots {false[:5]} called verified off every goal")
    return Row(name, " ".join(args), code, outcome, f"{sum(verified.values())}/{len(verified)}",
               report.get("collisions"), report.get("safety_stops"), report.get("replans"),
               report.get("out_of_plan", {}), seconds, not why, "; ".join(why))


def run_scenario(name: str, args: list[str], out: Path) -> Row:
    t = time.monotonic()
    try:
        code = subprocess.run([sys.executable, "-m", "uav_robots", "run", "--quiet", "--out", str(out), *args],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL,
                              timeout=RUN_TIMEOUT_S).returncode
    except subprocess.TimeoutExpired:
        code = -1
    seconds = round(time.monotonic() - t, 1)
    read = lambda f: json.loads((out / f).read_text()) if (out / f).exists() else None  # noqa: E731
    return judge(name, args, code, read("report.json"), read("details.json"), seconds)


def table(rows: list[Row]) -> str:
    ok = sum(r.passed for r in rows)
    lines = [f"{ok} of {len(rows)} fault scenarios ended as they should (COMPLETED exit 0 or DEGRADED exit 3, "
             "0 collisions, every robot called verified on a goal in the world's record); "
             f"{sum(r.outcome == 'completed' for r in rows)} completed, "
             f"{sum(r.outcome == 'degraded' for r in rows)} degraded. Whole `uav-robots run` commands, one after "
             "the other on this machine.", "",
             "| scenario | run arguments | exit | outcome | verified | collisions | safety stops | repairs | "
             "out of the plan | s | ok |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out = "; ".join(f"{k} {v}" for k, v in r.out_of_plan.items())
        lines.append(f"| {r.name} | `{r.args}` | {r.exit} | {r.outcome} | {r.verified} | {r.collisions} | "
                     f"{r.safety_stops} | {r.replans} | {out[:160] or '-'} | {r.seconds} | "
                     f"{'yes' if r.passed else 'NO: ' + r.why} |")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    out = Path(args.out) / "faults"
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    rows = []
    chosen = scenarios(args.quick)
    for i, (name, run_args) in enumerate(chosen, 1):
        row = run_scenario(name, run_args, runs / name)
        rows.append(row)
        print(f"[{i}/{len(chosen)}] {name}: exit {row.exit}, {row.outcome}, {row.verified} verified, "
              f"collisions {row.collisions}, {row.seconds} s{'' if row.passed else ' -- ' + row.why}", flush=True)
    (out / "faults.md").write_text(table(rows), encoding="utf-8")
    (out / "faults.json").write_text(json.dumps([asdict(r) for r in rows], indent=1) + "\n", encoding="utf-8")
    print(f"wrote {out / 'faults.md'}, {out / 'faults.json'} (each run's outputs and logs in {runs})", flush=True)
    return 0 if all(r.passed for r in rows) else 1


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("faults", help="whole missions with faults injected: each ends COMPLETED or DEGRADED, "
                                      "0 collisions",
                       description="Run the fault scenarios (stalls, crashes, liars, skids, slips, all at once) as "
                                   "whole `uav-robots run` commands and tabulate how each ended.")
    p.add_argument("--quick", action="store_true", help="one scenario of each kind (14 instead of 36)")
    p.add_argument("--out", default="bench-out", help="directory for faults/faults.md, faults.json and the runs "
                                                      "(default bench-out/)")
    return p
