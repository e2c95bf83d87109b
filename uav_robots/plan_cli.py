"""`uav-robots plan` and `uav-robots build`: planning alone, no processes, no drone; the planners compiled
ahead of time."""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from protocol.errors import UavRobotsError

from .common.arguments import REFINE_HELP, fail, positive_float, positive_int, seconds


# ---------------------------------------------------------------------------- plan

def add_plan_parser(subparsers) -> argparse.ArgumentParser:
    from scenarios.maps import MAP_HELP

    from uav_agent.planning.assignment import ASSIGNERS
    from uav_agent.planning.registry import DEFAULT_PLANNER, PLANNERS
    p = subparsers.add_parser(
        "plan", help="assign goals and plan collision-free paths; write a plan file",
        description="Plan alone (no processes, no drone): a map, robots and goals in, a validated "
                    "plan file out. With --scen the scenario's start-goal pairs are kept unless --assign "
                    "says otherwise; with --robots N --seed S robots and goals are placed at random and "
                    "assigned (optimal by default).")
    p.add_argument("--map", required=True, help=MAP_HELP)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--scen", help="a MovingAI .scen file: robots start and goal cells; with a shipped "
                                    "MovingAI map's name as --map, also its scenario's name (random-1, even-3)")
    src.add_argument("--robots", type=positive_int, help="place N robots and N goals at random (seeded)")
    p.add_argument("--agents", type=positive_int, help="with --scen: use the first N agents (default all)")
    p.add_argument("--seed", type=int, default=0, help="placement, random map and planner seed (default 0)")
    p.add_argument("--out", required=True, help="the plan file to write (JSON, uav-robots-plan/1)")
    # Not argparse choices: an unknown name gets the same one-line error as any bad input.
    p.add_argument("--planner", default=DEFAULT_PLANNER,
                   help=f"{', '.join(PLANNERS)}; default {DEFAULT_PLANNER} (the fastest complete one)")
    p.add_argument("--assign", choices=list(ASSIGNERS),
                   help="goal assignment (default: none with --scen, optimal with --robots)")
    p.add_argument("--connectivity", type=int, choices=(4, 8), default=4)
    p.add_argument("--time-limit", type=positive_float, default=60.0, help="seconds for the whole plan (default 60)")
    p.add_argument("--no-fallback", action="store_true",
                   help="fail instead of falling back to the default planner when an incomplete one fails")
    p.add_argument("--refine", type=seconds, default=0.0, metavar="S", help=REFINE_HELP)
    p.set_defaults(func=cmd_plan)
    return p


def _load_instance(args):
    from protocol.errors import MapError
    from protocol.mapfile import read_scen
    from scenarios.maps import place, resolve_map, shipped_movingai

    name, free = resolve_map(args.map, args.seed)
    if args.scen:
        shipped = None if Path(args.scen).is_file() else shipped_movingai(name, args.scen)
        # `--map room-64-64-8 --scen random-1`: the shipped scenario of that map
        agents = read_scen(shipped or args.scen, free, args.agents)
        if not agents:
            raise MapError(f"{args.scen}: the scenario has no agents")
        return name, free, [a.start for a in agents], [a.goal for a in agents], args.assign or "none"
    if args.agents is not None:
        raise MapError("--agents goes with --scen; with --robots the count is --robots")
    pl = place(free, args.robots, args.seed)
    return name, free, pl.starts, pl.goals, args.assign or "optimal"


def cmd_plan(args: argparse.Namespace) -> int:
    try:
        t0 = time.perf_counter()
        name, free, starts, goals, assign = _load_instance(args)
        t_load = time.perf_counter() - t0
        from uav_agent.planning.registry import check_name
        check_name(args.planner)     # a misspelt name is a one-line error before numba's start-up and the compile
        # Imported after the input is checked: numba's start-up need not delay a one-line error.
        from uav_agent.planning.pipeline import plan_mission
        from uav_agent.planning.plan_io import write_plan

        options = dict(planner=args.planner, assign=assign, connectivity=args.connectivity,
                       time_limit=args.time_limit, fallback=not args.no_fallback, seed=args.seed)
        result = _plan_interpreted(free, starts, goals, options, args.refine)
        if result is None:
            _compile_first(args.planner, args.connectivity)
            result = plan_mission(free, starts, goals, refine_s=args.refine, **options)
        write_plan(args.out, result, free, map_name=name)
    except UavRobotsError as exc:
        return fail(exc)
    _print_plan(name, free.shape, result, t_load, args.out)
    return 0


def _plan_interpreted(free, starts, goals, options: dict, refine_s: float):
    """On a fresh clone, an instance that `interpreted.fits` is planned by the planners interpreted
    (the same plan, in seconds: 50 robots on the 450 warehouse in 3 s) instead of after their
    compile; None otherwise. Not with --refine: its neighbourhoods are as many as its seconds allow,
    and interpreted far fewer fit."""
    from uav_agent.planning.build import warm
    from uav_agent.planning.build.interpreted import fits, plan_interpreted

    if refine_s or warm.is_warm() or not fits(free, len(starts), len(goals)):
        return None
    print("the planners' kernels are not compiled on this machine yet: planning with them interpreted "
          "(the same plan; `uav-robots build` compiles them once)", flush=True)
    try:
        return plan_interpreted(free, starts, goals, **options)
    except RuntimeError:      # the child could not run: the compiled kernels will
        return None


def _compile_first(planner: str, connectivity: int) -> None:
    """On a fresh clone, compile the kernels before the plan's clock starts: a compile inside
    the time limit cut the guide paths short (50 robots on the 450 warehouse: sum of costs
    14251 instead of 13851), and the same command must give the same plan on every run. The
    lock keeps a mission or another command from compiling the same cache at once."""
    from uav_agent.planning.build import warm
    if warm.is_warm():
        return
    from uav_agent.planning.build.warm import warm_up
    from uav_agent.planning.compile.lock import kernel_lock

    print("compiling the planners' kernels (first run on this machine only; later runs load numba's cache; "
          "`uav-robots build` compiles them ahead of time instead)", flush=True)
    with kernel_lock():
        if not warm.is_warm():       # unless another process just compiled them
            warm_up(planner, connectivity)


def _print_plan(name, shape, result, t_load: float, out: str) -> None:
    from rich.console import Console
    from rich.table import Table

    m, t = result.metrics, result.timings
    h, w = shape
    table = Table(show_header=False)
    table.add_column("")
    table.add_column("", justify="right")
    planner = result.planner + (f" (fell back from {result.requested})" if result.fell_back else "")
    table.add_row("planner", planner)
    table.add_row("assignment", result.assign)
    if "initial_sum_of_costs" in m:
        table.add_row("sum of costs before refinement", str(m["initial_sum_of_costs"]))
        table.add_row("refinement rounds", str(m["refine_rounds"]))
    table.add_row("sum of costs", str(m["sum_of_costs"]))
    table.add_row("lower bound", str(m["lower_bound"]))
    table.add_row("SoC / LB", f"{m['soc_over_lb']:.4f}")
    table.add_row("makespan", str(m["makespan"]))
    table.add_row("map + robots loaded", f"{t_load:.3f} s")
    for phase in ("distances", "assignment", "planning", "refinement", "validation", "total"):
        if phase in t:
            table.add_row(f"time: {phase}", f"{t[phase]:.3f} s")
    console = Console(width=100)
    console.print(f"{len(result.paths)} robots on {name} ({w}x{h}), {result.connectivity}-connected", markup=False)
    console.print(table)
    for note in result.notes:
        console.print(f"note: {note}", markup=False)
    console.print(f"wrote {out}", markup=False)


# ---------------------------------------------------------------------------- build

def add_build_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "build", help="compile the planners ahead of time (about a minute on two cores, once per machine)",
        description="Compile the planning kernels ahead of time into a shared library (numba's pycc and the "
                    "system's C compiler), beside numba's cache. Every later process loads it without numba: "
                    "`uav-robots plan` for 50 robots takes about 0.5 s instead of 1.2 s, and a first large "
                    "mission does not wait for a compile. Rebuild after changing the planners' code (a changed "
                    "source uses numba's JIT until then).")
    p.set_defaults(func=cmd_build)
    return p


def cmd_build(args) -> int:
    from uav_agent.planning.build import aot
    from uav_agent.planning.compile import cache
    if cache.built():
        print(f"the planner kernels are built already ({cache.build_dir()})")
        return 0
    lacking = aot.missing_tools()
    if lacking is not None:
        raise UavRobotsError(f"the ahead-of-time build needs {lacking}; the planners keep numba's JIT")
    print("compiling the planner kernels ahead of time (about a minute on two cores, half that when numba "
          "has compiled them already)...", flush=True)
    return aot.build_once()
