"""`uav-robots bench movingai`: MovingAI maps with the scenarios' own start-goal pairs (no assignment)."""
from __future__ import annotations

import argparse
import re

from protocol.errors import UavRobotsError

from ..common.arguments import REFINE_HELP, seconds
from .common import fmt, markdown_table, median_of, parse_sizes, print_now, save_results
from .instances import Job, add_instance_options, planner_name, run_all, run_row, warmup_lines

# LaCAM3 (C++) on warehouse-10-20-10-2-1, random-1, from bench-results/reference-solvers.md.
MOVINGAI_REFERENCE = {"warehouse-10-20-10-2-1": {50: 0.12, 100: 0.14, 200: 0.20, 400: 0.54, 1000: 2.43}}


def add_parser(sub) -> argparse.ArgumentParser:
    from uav_agent.planning.registry import DEFAULT_PLANNER, PLANNERS

    pm = sub.add_parser("movingai", help="MovingAI maps with the scenarios' own start-goal pairs",
                        description="MovingAI benchmark instances (no assignment): success rate, time, "
                                    "SoC / lower bound, makespan.")
    pm.add_argument("--maps", default="warehouse-10-20-10-2-1", help="comma-separated map names")
    pm.add_argument("--scens", default="random-1..5", help="e.g. random-1..5,even-1 (default random-1..5)")
    pm.add_argument("--agents", default="50,100,200,400", help="robot counts (comma-separated)")
    pm.add_argument("--planner", default=DEFAULT_PLANNER, help=f"{', '.join(PLANNERS)} (default {DEFAULT_PLANNER})")
    pm.add_argument("--refine", type=seconds, default=0.0, metavar="S", help=REFINE_HELP)
    add_instance_options(pm, 60.0)
    return pm


def parse_scens(text: str) -> list[str]:
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


def run(args: argparse.Namespace) -> int:
    planner = planner_name(args.planner)
    agents = parse_sizes(args.agents)
    scens = parse_scens(args.scens)
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
    outcomes, warmups = run_all(groups, args.warm_cache, "bench movingai")

    header = ["map", "N", "solved", "median s", "max s", "planning s", "SoC/LB", "makespan", "peak RSS MB",
              "LaCAM3 (C++) s"]
    rows, summary = [], []
    for m in maps:
        for n in agents:
            runs = [o for o in outcomes if o.job.tags["map"] == m and o.job.agents == n]
            ok = [o for o in runs if o.status == "ok"]
            med = median_of(o.timings.get("total") for o in ok)
            worst = max((o.timings["total"] for o in ok), default=None)
            plan_s = median_of(o.timings.get("planning") for o in ok)
            ratio = median_of(o.metrics.get("soc_over_lb") for o in ok)
            mk = median_of(o.metrics.get("makespan") for o in ok)
            rss = max((o.peak_rss_mb for o in runs if o.peak_rss_mb is not None), default=None)
            ref = MOVINGAI_REFERENCE.get(m, {}).get(n)
            fb = sum(o.fell_back for o in ok)
            solved = f"{len(ok)}/{len(runs)}" + (f" ({fb} fell back)" if fb else "")
            rows.append([m, str(n), solved, fmt(med), fmt(worst), fmt(plan_s), fmt(ratio, 4), fmt(mk, 0),
                         fmt(rss, 0), fmt(ref, 2)])
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
        + "; ".join(warmup_lines(warmups)),
    ]
    failures = [o for o in outcomes if o.status != "ok"]
    for o in failures[:10]:
        notes.append(f"{o.job.tags['map']} {o.job.tags['scen']} N={o.job.agents}: {o.status}: {o.error[:120]}")
    text = markdown_table(header, rows) + "\n\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    save_results(args.out, "movingai", "# MovingAI benchmark\n\n" + text, summary, [run_row(o) for o in outcomes])
    print_now(text)
    return 0
