"""`uav-robots bench command`: the whole `uav-robots plan` command, timed as a user runs it.

The only boundary at which our planner and a reference solver's binary can be compared
like for like is the whole process: interpreter start, imports, loading compiled kernels,
reading the map and scenario, planning, validating and writing the plan. Each size runs
`uav-robots plan` as a fresh process on the first N start-goal pairs of the paper's
scenario with the scenario's own goals (`--assign none`, as a MAPF solver is given them),
`--repeat` times, and the table gives the median wall time beside the in-process time
the same runs reported in their plan files, and the reference solvers' whole-process figures
(bench-results/reference-solvers.md, measured separately on the same instances).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from protocol.errors import UavRobotsError

from ..common.arguments import positive_int
from .common import markdown_table, parse_sizes, print_now, save_results

# LaCAM3 (C++) whole-process wall seconds, warehouse-450-random-1, first N pairs
# (bench-results/reference-solvers.md: measured by the team, not in this run).
LACAM3_WHOLE_S = {3: 0.11, 10: 0.30, 25: 0.33, 50: 0.45, 100: 0.86, 500: 5.67}
COMMAND_TIMEOUT_S = 600.0


def time_plan_command(map_spec: str, scen: Path, agents: int, out: Path,
                      kernels: str = "") -> tuple[float, dict[str, float]]:
    """Wall seconds of one `uav-robots plan` process, and the phase timings it wrote. `kernels`
    "jit" makes the process use numba's JIT even where an ahead-of-time build is there."""
    cmd = [sys.executable, "-m", "uav_robots", "plan", "--map", map_spec, "--scen", str(scen),
           "--agents", str(agents), "--assign", "none", "--out", str(out)]
    env = {**os.environ, "UAV_ROBOTS_KERNELS": kernels} if kernels else None
    start = time.perf_counter()
    try:
        done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              timeout=COMMAND_TIMEOUT_S, env=env)
    except subprocess.TimeoutExpired:
        raise UavRobotsError(f"uav-robots plan with {agents} agents took over {COMMAND_TIMEOUT_S:g} s") from None
    wall = time.perf_counter() - start
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise UavRobotsError(f"uav-robots plan with {agents} agents failed (exit {done.returncode}): {last}")
    return wall, json.loads(out.read_text())["timings"]


_LABEL = {"aot": "built ahead of time", "jit": "numba JIT"}


def add_parser(sub) -> argparse.ArgumentParser:
    pc = sub.add_parser("command", help="the whole `uav-robots plan` command, timed as fresh processes",
                        description="Wall time of whole `uav-robots plan` processes on the paper warehouse with the "
                                    "scenario's own pairs, beside their in-process time and LaCAM3's whole-process "
                                    "reference: the like-for-like comparison with a solver binary.")
    pc.add_argument("--sizes", default="3,10,25,50,100,500", help="robot counts (comma-separated)")
    pc.add_argument("--repeat", type=positive_int, default=5, help="processes per size; the median is reported")
    pc.add_argument("--data", metavar="DIR", help="a benchmark data directory laid out like scenarios/data/")
    pc.add_argument("--out", default="bench-out", help="directory for the markdown and CSV (default bench-out/)")
    return pc


def run(args: argparse.Namespace) -> int:
    from scenarios.benchmarks import paper_map_spec, paper_scen
    from uav_agent.planning.compile import cache

    # with a build, each size is timed both ways in turn; without one, numba's JIT alone
    modes = ["jit", "aot"] if cache.built() else ["jit"]
    sizes = parse_sizes(args.sizes)
    scen, map_spec = paper_scen(1, args.data), paper_map_spec(args.data)
    rows, summary, runs = [], [], []
    with tempfile.TemporaryDirectory(prefix="uavr-bench-cmd-") as tmp:
        # One untimed run of each first: the first process after an install may compile or load caches.
        for kernels in modes:
            time_plan_command(map_spec, scen, min(sizes), Path(tmp) / "warm.json", kernels)
        for n in sizes:
            walls: dict[str, list[float]] = {k: [] for k in modes}
            inside: dict[str, list[float]] = {k: [] for k in modes}
            for r in range(args.repeat):
                for kernels in modes:
                    wall, timings = time_plan_command(map_spec, scen, n, Path(tmp) / f"plan-{n}-{r}.json", kernels)
                    walls[kernels].append(wall)
                    inside[kernels].append(timings["total"])
                    runs.append({"agents": n, "repeat": r, "kernels": kernels, "wall_s": round(wall, 4),
                                 "in_process_s": timings["total"]})
            best = modes[-1]
            med = {k: statistics.median(v) for k, v in walls.items()}
            ins = {k: statistics.median(v) for k, v in inside.items()}
            ref = LACAM3_WHOLE_S.get(n)
            row = [str(n)]
            for k in modes:
                row += [f"{med[k]:.2f}", f"{min(walls[k]):.2f}-{max(walls[k]):.2f}", f"{ins[k]:.3f}"]
            record = {"agents": n, "kernels": best, "median_wall_s": med[best], "min_wall_s": min(walls[best]),
                      "max_wall_s": max(walls[best]), "median_in_process_s": ins[best], "lacam3_whole_s": ref}
            if len(modes) == 2:
                pair = statistics.median(a / j for a, j in zip(walls["aot"], walls["jit"]))
                row.append(f"{pair:.2f}")
                record.update({"median_wall_jit_s": med["jit"], "median_in_process_jit_s": ins["jit"],
                               "aot_over_jit_pairwise": pair})
            row += [f"{ref:.2f}" if ref else "-", f"{ref / med[best]:.2f}" if ref else "-"]
            rows.append(row)
            summary.append(record)
    header = ["N"]
    for k in modes:
        header += [f"whole command s, {_LABEL[k]} (median)", "range", f"in-process s, {_LABEL[k]}"]
    if len(modes) == 2:
        header.append("ahead / JIT, whole command (pairwise median)")
    header += ["LaCAM3 whole process s (reference)", f"LaCAM3 / ours ({_LABEL[modes[-1]]})"]
    notes = [
        f"Instance: the first N start-goal pairs of {scen.name} on the 450x450 paper warehouse, the scenario's own "
        f"goals (--assign none), 4-connected; {args.repeat} fresh processes of each kind"
        + (", in turn (JIT, then ahead of time)" if len(modes) == 2 else "") + ", after one untimed run of each.",
        "Whole command: wall time of `python -m uav_robots plan ... --out FILE`, from process start to exit "
        "(interpreter, imports, loading the kernels, map and scenario, planning, validation, writing the plan).",
        "Built ahead of time: the kernels of `uav-robots build` (uav_agent/planning/build/aot.py), loaded without numba; "
        "numba JIT: the command with UAV_ROBOTS_KERNELS=jit and numba's cache warm (numba's import and its "
        "compiler's set-up are in every process)" + ("" if len(modes) == 2 else
                                                      "; no build was there, so only the JIT was timed") + ".",
        "In-process: the `total` the same runs wrote in their plan files (loaded map to validated plan).",
        "LaCAM3: whole-process wall time of its binary on the same instances, measured by the team on a 2-core "
        "machine of this kind (bench-results/reference-solvers.md), not in this run; compare a whole-command "
        "column with it, never an in-process one.",
    ]
    text = markdown_table(header, rows) + "\n\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    save_results(args.out, "command", "# Whole `uav-robots plan` command (450x450 warehouse)\n\n" + text, summary, runs)
    print_now(text)
    return 0
