"""The verify phase: a Done is believed only when an image taken after it shows the robot on its
goal; the mission's outcome and its reason follow from what the camera verified."""
from __future__ import annotations

import time

from . import looks
from .context import MissionContext

DONE_WAIT_S = 5.0          # after the last tick: how long the Done flags may take to arrive


def run(ctx: MissionContext) -> None:
    """Believe a Done only when an image taken after it shows the robot on its goal."""
    plan, fleet, a, ids = ctx.plans.now, ctx.fleet, ctx.arrivals, ctx.plans.ids
    deadline = time.monotonic() + DONE_WAIT_S
    with fleet.cv:
        while not all(ctx.done_for(r, plan) for r in plan.ids) and time.monotonic() < deadline:
            ctx.check_vehicle()
            fleet.cv.wait(0.1)
        claimed = {r for r in ids if r in fleet.done}
    ctx.status("verify", message=f"a fresh look at {len(plan.ids)} robots' goals")
    goals = {r: ctx.plans.goal_of.get(r) for r in ids}
    # Only the goals matter: a robot anywhere else is not on its goal, seen or not. Arrivals
    # an image confirmed during execution need no second look.
    # The vehicle lands where the look ends, unless a repair follows (then it flies back anyway).
    confirmed = {r for r in plan.ids if a.confirmed.get(r) == plan.plan_id}
    cells = [tuple(g) for r, g in goals.items() if g is not None and r not in confirmed]
    ctx.progress.phase("verify", f"{len(confirmed)} arrival(s) seen during execution; a look at "
                                 f"{len(cells)} more goal(s)")
    looked_for = {r for r, g in goals.items() if g is not None and r not in confirmed}
    seen = looks.look(ctx, cells, back=False, expected=looked_for) if cells else {}
    nowhere = {r: tuple(goals[r]) for r in claimed if goals.get(r) is not None and r not in seen
               and r not in confirmed}
    if nowhere:
        seen.update(looks.closer_at_goals(ctx, nowhere))
    seen.update((r, tuple(goals[r])) for r in confirmed)
    a.seen_at_end = seen
    for r in ids:
        g = goals[r]
        a.verified[r] = g is not None and seen.get(r) == tuple(g)
        if r in claimed and not a.verified[r] and r not in a.contradicted:
            a.contradicted.add(r)
            where = f"on {seen[r]}" if r in seen else "nowhere"
            ctx.event("done-contradicted", [r], f"raised Done but the camera sees it {where}"
                                                + (f", not on its goal {tuple(g)}" if g else ""),
                      "counted as not arrived")
        elif r in plan.ids and r not in claimed and a.verified[r]:
            ctx.event("done-missing", [r], "on its goal but raised no Done", "counted as arrived (seen)")
    ctx.clock.lap("verify")


def outcome(ctx: MissionContext) -> str:
    """completed: every robot seen on a goal; degraded: every working robot is, some were lost; else failed."""
    verified = ctx.arrivals.verified
    if verified and all(verified.values()):
        return "completed"
    working = [r for r in ctx.plans.ids if r not in ctx.roster.blocked]
    if working and all(verified.get(r) for r in working):
        return "degraded"
    return "failed"


def reason(ctx: MissionContext) -> str:
    n, ok = len(ctx.plans.ids), sum(ctx.arrivals.verified.values())
    if outcome(ctx) == "completed":
        return f"all {n} robots verified on their goals"
    blocked, out_reason = ctx.roster.blocked, ctx.roster.out_reason
    out = "; ".join(f"{r} {out_reason.get(r, '')}".rstrip() for r in sorted(blocked)[:10])
    out += f"; ... {len(blocked) - 10} more" if len(blocked) > 10 else ""
    return f"{ok}/{n} robots verified on their goals; out of the plan: {out or 'none'}"
