"""`uav-robots bench secure`: what mutual TLS and access control cost, in execution ticks per second.

Boundary: whole `uav-robots run --json` commands (every process started and stopped), the
figure being the UAV's own execution phase: ticks / timings.execute from report.json, with
--monitor-every 0 so that no camera image falls inside it. Plain and --secure runs alternate
(the order flips each repetition) so that a change in machine load hits both alike.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from protocol.errors import UavRobotsError


def one_run(robots: int, map_spec: str, seed: int, secure: bool, timeout_s: float) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "uav_robots", "run", "--json", "--robots", str(robots), "--map", map_spec,
           "--seed", str(seed), "--monitor-every", "0", *(["--secure"] if secure else [])]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise UavRobotsError(f"a {'secure' if secure else 'plain'} run took over {timeout_s:g} s") from None
    lines = r.stdout.strip().splitlines()
    summary = json.loads(lines[-1]) if lines else {}
    if r.returncode != 0 or not summary.get("completed"):
        raise UavRobotsError(f"a {'secure' if secure else 'plain'} run failed (exit {r.returncode}): "
                             f"{summary.get('reason') or r.stderr.strip()[-300:]}")
    t = summary["timings"]
    return {"mode": "secure" if secure else "plain", "robots": robots, "seed": seed, "ticks": summary["ticks"],
            "execute_s": t["execute"], "ticks_per_s": round(summary["ticks"] / t["execute"], 1),
            "wall_s": t["wall_total"], "collisions": summary["collisions"]}


def table(runs: list[dict[str, Any]]) -> str:
    rows = ["| mode | runs | ticks | execution ticks/s (median) | all runs, ticks/s | whole run wall s (median) |",
            "|---|---|---|---|---|---|"]
    med: dict[str, float] = {}
    for mode in ("plain", "secure"):
        rs = [r for r in runs if r["mode"] == mode]
        med[mode] = statistics.median(r["ticks_per_s"] for r in rs)
        rows.append(f"| {mode} | {len(rs)} | {rs[0]['ticks']} | {med[mode]:.0f} | "
                    f"{', '.join(f'{r['ticks_per_s']:.0f}' for r in rs)} | "
                    f"{statistics.median(r['wall_s'] for r in rs):.2f} |")
    rows.append(f"\nsecure / plain execution ticks/s: {med['secure'] / med['plain']:.2f}")
    return "\n".join(rows)


def run_bench(args: argparse.Namespace) -> int:
    runs: list[dict[str, Any]] = []
    for i in range(args.repeat):
        for secure in ((False, True) if i % 2 == 0 else (True, False)):
            r = one_run(args.robots, args.map, args.seed, secure, args.run_timeout)
            print(f"  {r['mode']:6s} {r['ticks']} ticks in {r['execute_s']:.3f} s: {r['ticks_per_s']:.0f} ticks/s",
                  flush=True)
            runs.append(r)
    text = (f"# Security cost: execution ticks per second, plain vs --secure\n\n"
            f"`uav-robots bench secure --robots {args.robots} --map {args.map} --seed {args.seed} "
            f"--repeat {args.repeat}` ({os.cpu_count()} cores). Boundary: whole `uav-robots run` commands, "
            f"alternating; the figure is ticks / the UAV's execution phase (report.json), "
            f"--monitor-every 0.\n\n{table(runs)}\n")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "secure.md").write_text(text)
    (out / "secure-runs.json").write_text(json.dumps(runs, indent=1) + "\n")
    print(text, flush=True)
    return 0


def add_secure_bench(sub: Any) -> None:
    ps = sub.add_parser("secure", help="execution ticks/s with and without --secure, alternating",
                        description="Runs whole missions alternately plain and with --secure and compares "
                                    "execution ticks per second.")
    ps.add_argument("--robots", type=int, default=50, help="robots per run (default 50)")
    ps.add_argument("--map", default="warehouse:blocks_x=6,blocks_y=4", help="map of every run")
    ps.add_argument("--seed", type=int, default=0)
    ps.add_argument("--repeat", type=int, default=3, help="runs of each mode (default 3)")
    ps.add_argument("--run-timeout", type=float, default=600.0, help="seconds one run may take")
    ps.add_argument("--out", default="bench-out", help="directory for secure.md and secure-runs.json")
    ps.set_defaults(func=lambda a: run_bench(a))
