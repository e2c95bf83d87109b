"""The plan phase: the perceived floor's robots and goals to a plan, by the configured planner;
on a fresh clone's first run the same planners interpreted while their kernels compile."""
from __future__ import annotations

import threading

from protocol.errors import PlanningError

from .context import MissionContext


def start_warm_up(ctx: MissionContext) -> None:
    """The planners' kernels compiled (a fresh clone) or loaded while the vehicle flies the survey."""
    from ..planning.build.warm import is_warm

    c = ctx.compile
    c.compiling = not is_warm()   # a fresh clone: the kernels compile during the flight
    c.warm = threading.Thread(target=_warm_up, args=(ctx,), name="planner-warm-up", daemon=True)
    c.warm.start()


def start_interpreter(ctx: MissionContext) -> None:
    if ctx.compile.compiling:
        from ..planning.build.interpreted import InterpretedPlanner
        # its interpreter and imports while the vehicle climbs (the link's set-up before
        # took its CPU: the connection came 0.6 s later)
        ctx.compile.interpreter = InterpretedPlanner()


def _warm_up(ctx: MissionContext) -> None:
    from ..planning.build import warm
    from ..planning.compile.lock import kernel_lock
    from ..planning.registry import DEFAULT_PLANNER

    cfg = ctx.cfg
    try:
        # A cold cache is compiled by a process of its own (the launcher's, else one started
        # here): compiling on this thread would hold the GIL through the survey.
        if ctx.compile.compiling:
            warm.start(cfg.planner, cfg.connectivity)
        with kernel_lock():
            if not ctx.compile.skip_warm.is_set():   # planned without them: loading now would only stall
                warm.warm_up(cfg.planner or DEFAULT_PLANNER, cfg.connectivity)
    except Exception:  # noqa: BLE001 - the real plan call reports any problem properly
        pass


def plan(ctx: MissionContext, model):
    """The first plan, from the survey's model; its robots become the mission's."""
    from ..planning.registry import DEFAULT_PLANNER

    cfg = ctx.cfg
    ids = sorted(model.robots)
    planner = cfg.planner or DEFAULT_PLANNER
    starts = [model.robots[i] for i in ids]
    options = dict(planner=planner, assign=cfg.assign, connectivity=cfg.connectivity,
                   time_limit=cfg.time_limit_s, fallback=cfg.fallback, seed=cfg.seed)
    ctx.status("plan", message=f"{len(ids)} robots, planner {planner}, assignment {cfg.assign}")
    try:
        result = plan_mission(ctx, model.free, starts, list(model.goals), **options)
    except PlanningError:
        from ..perception.verdict import explain_unplannable

        # Robots or goals walled in by what the camera read as shelf: a perception failure.
        why = explain_unplannable(model, cfg.connectivity)
        if why is not None:
            raise why from None
        raise
    for note in result.notes:
        ctx.progress.phase("plan", note)
    ctx.plans.ids = ids
    ctx.plans.free = model.free
    ctx.plans.first = result
    ctx.clock.lap("plan")
    return result


def plan_mission(ctx: MissionContext, free, starts, goals, **options):
    """`plan_mission`; on a fresh clone's first run, while the kernels still compile, the same
    planners interpreted (a repair's plan too: planned in the UAV's process, the compile held
    the fleet 48 s after a robot was lost), else once the compile is done."""
    from ..planning.pipeline import plan_mission as plan_compiled

    c = ctx.compile
    if c.compiling and c.warm is not None and c.warm.is_alive():
        result = plan_while_compiling(ctx, free, starts, goals, options)
        if result is not None:
            return result
        if c.warm.is_alive():
            ctx.progress.phase("plan", "compiling the planners (first run on this machine only, ~30 s; "
                                       "later runs load numba's cache; `uav-robots build` compiles them "
                                       "ahead of time instead)")
    if c.warm is not None:
        c.warm.join()
    return plan_compiled(free, starts, goals, **options)


def plan_while_compiling(ctx: MissionContext, free, starts, goals, options):
    """The plan by the same planners interpreted, while their kernels still compile (a fresh
    clone's first run): a few seconds for the missions `uav-robots run` flies (the 450x450
    warehouse's 50 robots: about 2 s, against half a minute's wait); None when the instance is
    too large for that or the interpreted run failed: the caller then waits for the kernels."""
    from ..planning.build.interpreted import InterpretedPlanner, fits

    c = ctx.compile
    ahead, c.interpreter = c.interpreter, None   # the child started at takeoff serves once
    if not fits(free, len(starts), len(goals)):
        if ahead is not None:
            ahead.close()
        return None
    ctx.progress.phase("plan", "the planners' kernels are still compiling (first run on this machine "
                               "only): planning this instance with them interpreted")
    planner = ahead or InterpretedPlanner()
    try:
        result = planner.plan(free, starts, goals, **options)
        c.skip_warm.set()
        return result
    except (PlanningError, RuntimeError) as exc:
        ctx.progress.phase("plan", f"interpreted planning failed ({str(exc).splitlines()[0]}); "
                                   "waiting for the compiled kernels")
        return None
    finally:
        planner.close()
