"""The execute phase: the fleet ticked in lockstep, each tick's states checked against the plan,
images taken between ticks, a fault repaired at the tick it is found; after the last tick the
fleet is held in place while robots out of the plan may still come back."""
from __future__ import annotations

import time

from protocol.messages import Tick
from protocol.codec import encode

from . import dispatch, monitor, movers, repair
from .context import MissionContext
from .state import PlanState

# After the plan's last tick, robots out of the plan whose session is still up (stalled, not lost)
# may come back; they show life only on a tick, so the fleet is ticked in place for this many tick
# timeouts, a tick every HOLD_TICK_S.
REJOIN_HOLD_TIMEOUTS = 2.0
HOLD_TICK_S = 0.1


def run(ctx: MissionContext) -> None:
    cfg, fleet, a = ctx.cfg, ctx.fleet, ctx.arrivals
    end = ctx.plans.now.end_tick
    ctx.status("executing", tick=0, ticks=end, robots=len(ctx.plans.ids), message="")
    ctx.progress.phase("execute", f"{end} ticks, {len(ctx.plans.ids)} robots in lockstep")
    period = 1.0 / cfg.tick_rate_hz if cfg.tick_rate_hz > 0 else 0.0
    a.exec_t0, a.exec_k0 = time.perf_counter(), ctx.tick
    next_at = time.monotonic()
    hold_until: float | None = None
    while True:
        pace = period
        if ctx.tick >= ctx.plans.now.end_tick:
            hold_until = hold_for_rejoin(ctx, hold_until)
            if hold_until is None:
                break
            pace = max(period, HOLD_TICK_S)
        ctx.check_vehicle()
        if pace:
            next_at += pace
            time.sleep(max(0.0, next_at - time.monotonic()))
        off = movers.look_if_due(ctx, ctx.tick)
        lost = movers.goals_lost(ctx, ctx.tick)
        if off or lost:
            repaired(ctx, ctx.tick, {k: v for k, v in (("deviation", off), ("goal-lost", lost)) if v})
        around = movers.before_tick(ctx, ctx.tick)
        if around is not None:
            repaired_around(ctx, around)
        plan = ctx.plans.now
        k = ctx.tick = ctx.tick + 1
        with fleet.cv:   # a state for tick k is a robot's only once Tick(k) is out
            fleet.clock = max(fleet.clock, k)
        ctx.transport.put(ctx.keys.tick, encode(Tick(k=k, ticks=plan.end_tick, plan_id=plan.plan_id,
                                                      batch_states=True, seq=ctx.next_seq())))
        faults = fleet.wait_tick(plan.ids, k, cfg.tick_timeout_s, interrupt=ctx.interrupted)
        ctx.check_vehicle()
        if not faults:
            with fleet.cv:
                off = [r for r in plan.ids if fleet.cells.get(r) != plan.cell(r, k)]
            if off:
                faults = {"deviation": off}
        if not faults:
            off = monitor.seen(ctx)
            if off:
                faults = {"deviation": off}
            else:
                monitor.between_ticks(ctx, k)
        if not faults:
            back = repair.rejoining(ctx)
            if back:
                faults = {"rejoin": back}
        if faults:
            repaired(ctx, k, faults)
            next_at = time.monotonic()
            hold_until = None
        elif ctx.roster.strikes:
            moved_cleanly(ctx, plan, k)
        done = sum(1 for r in plan.ids if ctx.done_for(r, plan))
        end = ctx.plans.now.end_tick
        ctx.progress.ticks(k, end, done, len(plan.ids))
        if k % 10 == 0 or k == end:
            ctx.status("executing", tick=k, ticks=end, done=done, robots=len(ctx.plans.ids))
    monitor.last_looks(ctx)
    ctx.clock.lap("execute")


def repaired(ctx: MissionContext, k: int, faults: dict[str, list[int]]) -> None:
    """The fleet held at tick k and repaired; robots that do not take the repair are faults of their own."""
    while faults:
        plan = repair.recover(ctx, k, faults)
        failed = dispatch.send(ctx, plan)
        faults = {"error": failed} if failed else {}


def repaired_around(ctx: MissionContext, plan: PlanState) -> None:
    """A plan repaired around the movers, sent before its first tick; robots that do not take it are
    faults of their own (a robot keeping its old plan could walk into a mover: it is held first)."""
    failed = dispatch.send(ctx, plan)
    if failed:
        repaired(ctx, ctx.tick, {"error": failed})


def hold_for_rejoin(ctx: MissionContext, until: float | None) -> float | None:
    """After the plan's last tick: while robots out of the plan may still come back (their session
    is up: stalled, not lost), the fleet is ticked in place, until REJOIN_HOLD_TIMEOUTS tick
    timeouts have passed; a stall counted in ticks, or a robot frozen for a while, ends so. Returns
    when the hold ends (None: it is over, or nobody is waited for)."""
    roster = ctx.roster
    with ctx.fleet.cv:
        waited = sorted(r for r in roster.blocked if r in ctx.fleet.alive and r not in roster.quarantined)
    if not waited:
        return None
    now = time.monotonic()
    if until is None:
        hold = REJOIN_HOLD_TIMEOUTS * ctx.cfg.tick_timeout_s
        ctx.event("hold", waited, "out of the plan, their sessions still up",
                  f"ticking the fleet in place for up to {hold:g} s for them to come back")
        return now + hold
    if now >= until:
        ctx.event("hold-over", waited, "did not come back", "the mission ends without them")
        return None
    return until


def moved_cleanly(ctx: MissionContext, plan: PlanState, k: int) -> None:
    """A tick kept by every robot: those with strikes that made a planned move in it count it. A
    state alone proves nothing (a skidding drive tells its robot it arrived), but the world accepting
    the next move from the cell the robot believed proves the move before it: two in a row clear."""
    roster = ctx.roster
    for r in [r for r in roster.strikes if r in plan.paths and k > plan.start_tick
              and plan.cell(r, k) != plan.cell(r, k - 1)]:
        roster.clean_moves[r] = roster.clean_moves.get(r, 0) + 1
        if roster.clean_moves[r] >= 2:
            roster.forgive([r])
