"""Repair: the fleet held at a tick, a fresh look, the robots that cannot move taken out of the
plan (for good once they keep failing), and a new plan for the rest from where the camera sees
them. `recover` returns that plan; the caller dispatches it."""
from __future__ import annotations

import secrets
import time

from protocol.errors import MissionError, PlanningError

from . import looks, plan as planning
from .context import MissionContext
from .state import PlanState

# A robot named in this many repairs without a planned move it made between them keeps failing
# (deviating, stalling, erring): it is quarantined, out of the plan for good, not allowed to sink
# the others. A slipping robot fails now and then, and its moves between reset the count.
MAX_STRIKES = 3
# Repairs in a row that bring the fleet no nearer its goals (the repaired plan's lower bound is not
# below the best one since the working robots last changed): then the robots they named are quarantined.
MAX_FRUITLESS = 10


def recover(ctx: MissionContext, k: int, faults: dict[str, list[int]]) -> PlanState:
    """Hold the fleet at tick k, look, take the robots that cannot move out of the plan, replan the rest.
    A robot that keeps failing is quarantined; robots the camera verified on their goals stay there."""
    from ..planning.registry import DEFAULT_PLANNER
    from ..recovery import replan

    cfg, roster, plans, fleet = ctx.cfg, ctx.roster, ctx.plans, ctx.fleet
    t = time.perf_counter()
    roster.replans += 1
    faulty = set(faults.get("lost", [])) | set(faults.get("error", [])) | set(faults.get("stalled", [])) \
        | set(faults.get("goal-lost", []))
    for kind, robots in faults.items():
        if not robots:
            continue
        what = {"lost": "liveliness gone", "error": "reported status error",
                "stalled": f"no state for tick {k} within {cfg.tick_timeout_s:g} s",
                "deviation": "reported a cell off its plan", "rejoin": "back and reporting",
                "goal-lost": "its goal lies under a pallet"}[kind]
        ctx.event(f"robot-{kind}", robots, what, f"fleet held at tick {k}; fresh look; replan")
    ctx.status("recover", message=f"tick {k}: {', '.join(f'{a} {b}' for a, b in faults.items())}")
    # Hold at the tick boundary: the robots still working finish tick k before the look, so the
    # image shows a settled floor (a lost robot is noticed while the others are mid-tick).
    settling = [r for r in plans.now.ids if r not in faulty]
    fleet.wait_tick(settling, k, cfg.tick_timeout_s, interrupt=ctx.interrupted)
    ctx.check_vehicle()
    seen = looks.look(ctx)
    with fleet.cv:
        alive = set(fleet.alive)
        reported = dict(fleet.cells)
        fleet.errors.clear()
    for r in faults.get("rejoin", []):
        roster.bring_back(r)
    kind_of = {r: kind for kind, robots in faults.items() if kind != "rejoin" for r in robots}
    working = _sort_out(ctx, seen, alive, reported, faulty, kind_of)
    now = plans.now
    also = sorted(r for r in working if r in now.paths and r not in kind_of and working[r] != now.cell(r, k))
    if also:
        ctx.event("camera-deviation", also, f"the fresh look found them off their plan after tick {k}",
                  "replanned from where they are")
    unseen = [r for r in plans.ids if r not in seen]
    if unseen:
        ctx.event("unseen", unseen, "not seen by the fresh look", "kept out of the plan")
    # Unseen robots count too: one the camera keeps missing would otherwise rejoin and be left out
    # again at every tick.
    culprits = {**{r: "unseen" for r in unseen if r in now.paths}, **kind_of, **{r: "deviation" for r in also}}
    # Seen on its plan's cell, or back and seen: a fresh start (a robot that stalled once and came
    # back is not one slip away from quarantine).
    roster.forgive([r for r in roster.strikes if r in working and r not in culprits and
                    (r in faults.get("rejoin", []) or r in now.paths and working[r] == now.cell(r, k))])
    for r in strike(ctx, k, culprits):
        if r in working:
            roster.take_out(r, working.pop(r))
    lost = sorted(set(plans.ids) - alive)
    t_look = time.perf_counter() - t
    t = time.perf_counter()
    pid = now.plan_id
    confirmed = ctx.arrivals.confirmed
    pinned = {r: plans.goal_of[r] for r in working
              if confirmed.get(r) == pid and working[r] == tuple(plans.goal_of.get(r, ()))}
    try:
        rep = replan(plans.free, list(plans.model.goals), working, roster.blocked,
                     planner=cfg.planner or DEFAULT_PLANNER, connectivity=cfg.connectivity,
                     time_limit=cfg.time_limit_s, seed=cfg.seed,
                     plan=lambda *a, **kw: planning.plan_mission(ctx, *a, **kw), pinned=pinned)
    except PlanningError as exc:
        # The mission's input was fine; what happened to its fleet ends it: a failed mission
        # (exit 1), not a bad input (exit 2), as the UAV alone used to say.
        raise MissionError(f"no repair after tick {k}: {exc}") from None
    for r, why in rep.stranded.items():
        quarantine(ctx, r, f"stranded: {why}", working.pop(r))
    # A goal under a stopped robot that had reached it is served, not lost.
    plans.unserved = [tuple(g) for g in rep.unserved
                      if not any(plans.goal_of.get(r) == tuple(g) and c == tuple(g) for r, c in roster.blocked.items())]
    _count_progress(ctx, rep, culprits)
    new = PlanState(secrets.token_hex(4), k, rep.paths, rep.goals)
    ctx.event("replan", rep.ids, f"plan {new.plan_id} from tick {k} for {len(rep.ids)} robots "
                                 f"({len(rep.pinned)} kept on their verified goals; {len(roster.blocked)} out: "
                                 f"{sorted(roster.blocked)}, lost {lost}); {len(plans.unserved)} goal(s) unserved",
              f"looked in {t_look:.2f} s, replanned in {time.perf_counter() - t:.3f} s")
    ctx.clock.add("recover_look", t_look)
    return new


def _sort_out(ctx: MissionContext, seen, alive, reported, faulty, kind_of) -> dict:
    """The robots that work on (alive, seen, not faulty, not out) -> where the camera sees them; the
    others out of the plan at the cell best known, with the reason they are out."""
    roster = ctx.roster
    working = {}
    for r in ctx.plans.ids:
        cell = seen.get(r) or reported.get(r) or roster.blocked.get(r)
        if r in faulty or r in roster.blocked or r not in alive or r not in seen:
            if cell is not None:
                roster.blocked[r] = tuple(cell)
                if r not in roster.blocked_at or r in faulty:
                    roster.blocked_at[r] = time.monotonic()
            if r not in roster.quarantined:
                roster.out_reason[r] = ("lost: liveliness gone" if r not in alive else
                                        kind_of.get(r) or roster.out_reason.get(r) or "not seen by the fresh look")
        else:
            working[r] = seen[r]
    return working


def strike(ctx: MissionContext, k: int, culprits: dict[int, str]) -> list[int]:
    """Count each robot's fault; returns the robots quarantined now: MAX_STRIKES faults without a
    planned move between, or named by MAX_FRUITLESS repairs in a row that got the fleet no nearer."""
    roster = ctx.roster
    out = []
    for r, kind in culprits.items():
        roster.clean_moves.pop(r, None)
        roster.strikes.setdefault(r, []).append(f"{kind}@{k}")
        if len(roster.strikes[r]) >= MAX_STRIKES and r not in roster.quarantined:
            out.append(r)
            quarantine(ctx, r, f"{len(roster.strikes[r])} faults in a row, never shown on its plan between "
                               "(an image, or two moves kept in a row): " + ", ".join(roster.strikes[r]))
    if roster.fruitless >= MAX_FRUITLESS:
        named = sorted((roster.fruitless_culprits | set(culprits)) - set(roster.quarantined))
        for r in named:
            out.append(r)
            quarantine(ctx, r, f"named by {roster.fruitless} repairs in a row that brought the fleet "
                               "no nearer its goals")
        roster.fruitless, roster.fruitless_culprits = 0, set()
    return out


def quarantine(ctx: MissionContext, robot: int, why: str, cell=None) -> None:
    """Out of the plan for good: its cell an obstacle, its goal given to another, never rejoined."""
    roster = ctx.roster
    roster.quarantined[robot] = why
    roster.out_reason[robot] = f"quarantined: {why}"
    if cell is not None:
        roster.take_out(robot, cell)
    ctx.event("robot-quarantined", [robot], why, "out of the plan for good; the others go on")


def _count_progress(ctx: MissionContext, rep, culprits: dict[int, str]) -> None:
    """Whether this repair got the fleet nearer its goals than any before it with the same working
    robots (a lower bound below the best); repairs that do are not failures."""
    roster = ctx.roster
    working = frozenset(rep.ids)
    best = roster.best_lb
    if best is None or best[0] != working or rep.lower_bound < best[1]:
        roster.best_lb = (working, rep.lower_bound)
        roster.fruitless, roster.fruitless_culprits = 0, set()
    else:
        roster.fruitless += 1
        roster.fruitless_culprits |= set(culprits)


def rejoining(ctx: MissionContext) -> list[int]:
    """Robots taken out of the plan that are back: alive, heard of since, no error, not quarantined."""
    roster, fleet = ctx.roster, ctx.fleet
    with fleet.cv:
        return sorted(r for r in roster.blocked if r in fleet.alive and r not in fleet.errors
                      and r not in roster.quarantined
                      and fleet.heard.get(r, 0.0) > roster.blocked_at.get(r, 0.0))


def off_goal(ctx: MissionContext) -> list[int]:
    """Working robots the last look did not find on their goals (a skid, a late slip): replanned."""
    with ctx.fleet.cv:
        alive = set(ctx.fleet.alive)
    verified, blocked = ctx.arrivals.verified, ctx.roster.blocked
    return sorted(r for r in ctx.plans.now.ids if not verified.get(r) and r in alive and r not in blocked)


def drop_the_gone(ctx: MissionContext) -> None:
    """Robots of the plan whose session went away after its last tick, and that no image shows on
    their goal: lost, out of the plan (nothing to repair: they cannot move)."""
    roster, plan, fleet = ctx.roster, ctx.plans.now, ctx.fleet
    with fleet.cv:
        gone = sorted(r for r in plan.ids if r not in fleet.alive and not ctx.arrivals.verified.get(r)
                      and r not in roster.blocked)
    if not gone:
        return
    ctx.event("robot-lost", gone, "liveliness gone after the last tick, not seen on its goal", "out of the plan")
    for r in gone:
        roster.take_out(r, fleet.cells.get(r) or plan.cell(r, ctx.tick))
        roster.out_reason[r] = "lost: liveliness gone"

