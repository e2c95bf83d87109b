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
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from protocol.errors import UavRobotsError

# LaCAM3 (C++) whole-process wall seconds, warehouse-450-random-1, first N pairs
# (bench-results/reference-solvers.md: measured by the team, not in this run).
LACAM3_WHOLE_S = {3: 0.11, 10: 0.30, 25: 0.33, 50: 0.45, 100: 0.86, 500: 5.67}
COMMAND_TIMEOUT_S = 600.0


def time_plan_command(map_spec: str, scen: Path, agents: int, out: Path) -> tuple[float, dict[str, float]]:
    """Wall seconds of one `uav-robots plan` process, and the phase timings it wrote."""
    cmd = [sys.executable, "-m", "uav_robots", "plan", "--map", map_spec, "--scen", str(scen),
           "--agents", str(agents), "--assign", "none", "--out", str(out)]
    start = time.perf_counter()
    try:
        done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              timeout=COMMAND_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise UavRobotsError(f"uav-robots plan with {agents} agents took over {COMMAND_TIMEOUT_S:g} s") from None
    wall = time.perf_counter() - start
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise UavRobotsError(f"uav-robots plan with {agents} agents failed (exit {done.returncode}): {last}")
    return wall, json.loads(out.read_text())["timings"]


def run_command_bench(args: argparse.Namespace) -> int:
    from scenarios.benchmarks import paper_map_spec, paper_scen

    from .bench import _markdown, _print, _save, _sizes

    sizes = _sizes(args.sizes)
    scen, map_spec = paper_scen(1, args.data), paper_map_spec(args.data)
    rows, summary, runs = [], [], []
    with tempfile.TemporaryDirectory(prefix="uavr-bench-cmd-") as tmp:
        # One untimed run first: the first process after an install may compile or load caches.
        time_plan_command(map_spec, scen, min(sizes), Path(tmp) / "warm.json")
        for n in sizes:
            walls, inside = [], []
            for r in range(args.repeat):
                wall, timings = time_plan_command(map_spec, scen, n, Path(tmp) / f"plan-{n}-{r}.json")
                walls.append(wall)
                inside.append(timings["total"])
                runs.append({"agents": n, "repeat": r, "wall_s": round(wall, 4), "in_process_s": timings["total"]})
            wall, ins = statistics.median(walls), statistics.median(inside)
            ref = LACAM3_WHOLE_S.get(n)
            rows.append([str(n), f"{wall:.2f}", f"{min(walls):.2f}-{max(walls):.2f}", f"{ins:.3f}",
                         f"{wall - ins:.2f}", f"{ref:.2f}" if ref else "-", f"{ref / wall:.2f}" if ref else "-"])
            summary.append({"agents": n, "median_wall_s": wall, "min_wall_s": min(walls), "max_wall_s": max(walls),
                            "median_in_process_s": ins, "lacam3_whole_s": ref})
    header = ["N", "whole command s (median)", "range", "in-process s (same runs)", "outside planning s",
              "LaCAM3 whole process s (reference)", "LaCAM3 / ours"]
    notes = [
        f"Instance: the first N start-goal pairs of {scen.name} on the 450x450 paper warehouse, the scenario's own "
        f"goals (--assign none), 4-connected; median of {args.repeat} fresh processes after one untimed run.",
        "Whole command: wall time of `python -m uav_robots plan ... --out FILE`, from process start to exit "
        "(interpreter, imports, kernel cache load, map and scenario, planning, validation, writing the plan).",
        "In-process: the `total` the same runs wrote in their plan files (loaded map to validated plan).",
        "LaCAM3: whole-process wall time of its binary on the same instances, measured by the team on a 2-core "
        "machine of this kind (bench-results/reference-solvers.md), not in this run; compare the whole-command "
        "column with it, never the in-process one.",
    ]
    text = _markdown(header, rows) + "\n\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    _save(args.out, "command", "# Whole `uav-robots plan` command (450x450 warehouse)\n\n" + text, summary, runs)
    _print(text)
    return 0
