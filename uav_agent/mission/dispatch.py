"""Dispatch: a plan checked by the independent validator, sent to each robot, resent until
acknowledged; robots of an older protocol served or, under access control, refused."""
from __future__ import annotations

import dataclasses
import time

from protocol.errors import MissionError
from protocol.messages import PROTOCOL_VERSION, Plan
from protocol.codec import encode

from . import monitor
from .context import MissionContext
from .state import PlanState

PLAN_RESEND_S = 2.0        # a plan not acknowledged within this is put again


def send(ctx: MissionContext, plan: PlanState, first: bool = False) -> list[int]:
    """Check the plan, send it, wait for the acknowledgements; returns the robots that failed to take it."""
    from ..planning.types import Problem
    from ..planning.validator import check

    cfg, fleet = ctx.cfg, ctx.fleet
    ids = plan.ids
    free = ctx.plans.free.copy()
    for x, y in ctx.roster.blocked.values():
        free[y, x] = False
    # The validator is independent of the planners: nothing unchecked leaves the UAV.
    check(Problem(free, [tuple(plan.paths[r][0]) for r in ids], [plan.goals[r] for r in ids],
                  cfg.connectivity), [plan.paths[r] for r in ids])
    if first:
        ctx.status("dispatch", message=f"waiting for {len(ids)} robots to be alive, then sending plans")
        fleet.wait_until(lambda: set(ids) <= fleet.alive, cfg.startup_timeout_s,
                         lambda: f"robots {sorted(set(ids) - fleet.alive)[:10]} never came alive "
                                 f"within {cfg.startup_timeout_s:g} s")
    ctx.plans.now = plan
    ctx.plans.goal_of.update(plan.goals)
    monitor.plan_stops(ctx, plan)
    pid = plan.plan_id
    acked = lambda r: fleet.acks.get(r) is not None and fleet.acks[r].plan_id == pid  # noqa: E731
    deadline = time.monotonic() + cfg.startup_timeout_s
    try:
        while True:
            # A plan put before a robot's subscriber was ready is lost; robots acknowledge a
            # resent plan again, so resending to the silent ones is safe.
            for rid in (r for r in ids if not acked(r)):
                ctx.transport.put(ctx.keys.plan(rid), encode(Plan(
                    robot=rid, plan_id=pid, path=plan.paths[rid], goal=plan.goals[rid],
                    start_tick=plan.start_tick, connectivity=cfg.connectivity, seq=ctx.next_seq())))
            try:
                fleet.wait_until(lambda: all(acked(r) for r in ids),
                                 min(PLAN_RESEND_S, max(0.0, deadline - time.monotonic())),
                                 lambda: f"robots {[r for r in ids if not acked(r)][:10]} did not "
                                         f"acknowledge plan {pid} within {cfg.startup_timeout_s:g} s",
                                 abort=lambda: fleet.lost_among(ids))
                break
            except MissionError:
                if time.monotonic() >= deadline or fleet.lost_among(ids):
                    raise
    except MissionError as exc:
        if first:
            raise
        ctx.event("dispatch", [r for r in ids if not acked(r)], str(exc))
    older_protocols(ctx, [r for r in ids if acked(r)])
    with fleet.cv:
        failed = [r for r in ids if not acked(r) or not fleet.acks[r].ok]
    refused = [(r, fleet.acks[r].error) for r in failed if acked(r)]
    if refused and first:
        raise MissionError(f"robot {refused[0][0]} refused its plan: {refused[0][1]}")
    for r, why in refused:
        ctx.event("plan-refused", [r], why)
    if first:
        reach_hover(ctx)
        ctx.clock.lap("dispatch")
    return failed


def older_protocols(ctx: MissionContext, ids: list[int]) -> None:
    """Robots whose PlanAck states an older protocol (docs/protocol.md, Versioning): under access control
    refused, their ack made a refusal naming what they lack; otherwise served, said once per robot."""
    fleet = ctx.fleet
    with fleet.cv:
        older = {r: fleet.acks[r].protocol for r in ids
                 if fleet.acks[r].ok and fleet.acks[r].protocol < PROTOCOL_VERSION}
        if ctx.secured:
            for r, version in older.items():
                fleet.acks[r] = dataclasses.replace(fleet.acks[r], ok=False, error=(
                    f"robot {r} keeps protocol {version}: it asks its moves on P/world/move, which access "
                    f"control leaves unreachable; it needs protocol {PROTOCOL_VERSION} (docs/protocol.md, "
                    "Versioning)"))
            return
    for r, version in older.items():
        if r not in ctx.older_said:
            ctx.older_said.add(r)
            ctx.event("older-protocol", [r], f"robot {r} keeps protocol {version}: served, but it refuses a "
                      "repair that does not start where it believes it stands (it reads no start_tick)"
                      + (" and a diagonal step unless started with 8-connectivity (it reads no connectivity)"
                         if ctx.cfg.connectivity == 8 else ""),
                      "a repair it refuses takes it out of the plan")


def reach_hover(ctx: MissionContext) -> None:
    """Wait until the vehicle holds at the hover pose the survey sent it to; unless arrival
    stops are to be flown from the first tick on (a floor of several poses, whose hover
    sees only part of it): then the vehicle turns to the first stop from wherever it is."""
    v = ctx.vantage
    n, e, alt = v.hover
    if len(v.poses) == 1 or not ctx.arrivals.stops:
        n, e, down = ctx.flight.goto(n, e, alt)
        alt = -down
        ctx.track_altitude()
    c = ctx.info.cell_size_m
    ctx.uav["hover"] = [round(e / c, 2), round(-n / c, 2), round(alt, 2)]
