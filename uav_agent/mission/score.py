"""The mission scored: the world's record asked for after the flight, held against what the UAV
believes, and the report filled from both and written (completed, or aborted with its reason)."""
from __future__ import annotations

import os

from protocol.errors import MissionError
from protocol.messages import Record, RecordRequest

from .. import report as report_files
from .. import world_query
from . import movers, verify
from .context import MissionContext


def record(ctx: MissionContext, timeout_s: float = world_query.QUERY_TIMEOUT_S) -> Record | None:
    if ctx.fleet.world_gone:
        return None
    try:
        return world_query.query(ctx.transport, ctx.keys.record, RecordRequest(seq=ctx.next_seq()), Record, "record",
                             timeout_s)
    except MissionError:
        return None


def cross_check(ctx: MissionContext, rec: Record) -> None:
    """The world's record against what the UAV believes: any disagreement is reported."""
    hits = [f for f in rec.refused if f.get("collision")]
    if hits:
        ctx.event("collision", sorted({f["robot"] for f in hits}), f"the world refused {len(hits)} illegal "
                  f"move(s), first at tick {hits[0]['tick']}: {hits[0]['reason']}")
    vehicle = (rec.truth or {}).get("vehicle")
    uav = ctx.uav
    if vehicle:
        if uav["landed"] and (vehicle.get("armed") or vehicle.get("landed_state") != "ON_GROUND"):
            ctx.event("record-mismatch", [], f"the UAV believes it landed; the vehicle says armed "
                                             f"{vehicle.get('armed')}, {vehicle.get('landed_state')}")
        crashes = [text for _, text in vehicle.get("events", []) if "hit the ground" in text]
        if crashes:
            # A touchdown that hard is a crash, not a landing, whatever the UAV believed.
            uav["landed"], uav["crashed"] = False, True
            ctx.event("vehicle", [], f"the vehicle's own record: {crashes[0]}")
    seen = ctx.arrivals.seen_at_end
    for rid, cells in rec.executed.items():
        r = int(rid)
        if cells and r in seen and tuple(cells[-1]) != tuple(seen[r]):
            ctx.event("record-mismatch", [r], f"the world's record ends on {tuple(cells[-1])}, "
                                              f"the camera saw {tuple(seen[r])}")


def movers_summary(rec: Record | None) -> dict:
    """The world's movers in the report's top level (their trace stays in `truth`): robot-mover
    collisions (counted in `collisions` too) and near misses; nothing on a floor without movers."""
    movers = (rec.truth or {}).get("movers") if rec else None
    if not movers:
        return {}
    return {"mover_collisions": movers.get("collisions", 0), "near_misses": movers.get("near_misses", 0),
            "near_miss_ticks": movers.get("near_miss_ticks", 0), "movers": len(movers.get("movers", []))}


def fill(ctx: MissionContext, rec: Record | None, outcome: str, reason: str) -> None:
    from protocol.mapfile import format_rows

    from ..planning.plan_io import plan_to_dict

    plans, roster, a, fleet = ctx.plans, ctx.roster, ctx.arrivals, ctx.fleet
    ids, model, result = plans.ids, plans.model, plans.first
    ctx.report.update({
        "completed": outcome == "completed" and rec is not None and rec.collisions == 0,
        "outcome": outcome,
        "reason": reason,
        "robots": len(ids),
        "done": sorted(r for r in fleet.done if r in ids),
        "foreign_messages": fleet.foreign,
        "verified": {str(r): a.verified.get(r, False) for r in ids},
        "verified_during_execution": sorted(r for r, pid in a.confirmed.items()
                                            if plans.now is not None and pid == plans.now.plan_id),
        "lost": sorted(roster.blocked),
        "out_of_plan": {str(r): roster.out_reason.get(r, "") for r in sorted(roster.blocked)},
        "quarantined": sorted(roster.quarantined),
        "unserved_goals": [list(g) for g in movers.unserved(ctx)],
        "replans": roster.replans,
        "monitor_images": a.monitored,
        "events": ctx.events.as_dicts(),
        "collisions": rec.collisions if rec else None,
        "safety_stops": (rec.truth or {}).get("safety_stops", 0) if rec else None,
        **movers_summary(rec),
        **movers.report(ctx),
        "refused": rec.refused if rec else [],
        "ticks": ctx.tick,
        "plan": plan_to_dict(result, model.free, ids=ids) if result is not None else None,
        "executed": rec.executed if rec else {},
        "perceived": None if model is None else {
            "rows": format_rows(model.free), "robots": {str(i): list(c) for i, c in sorted(model.robots.items())},
            "goals": [list(g) for g in model.goals], "images": len(ctx.frames),
            "unsure": [list(c) for c in model.unsure],
            "registration": report_files.registration_summary(ctx.perception_frames),
            "warnings": ctx.perception_warnings},
        "truth": rec.truth if rec else None,
        "uav": ctx.uav,
        "timings": ctx.clock.timings,
        "processes": {"uav": os.getpid()},
        "fleet": ctx.cfg.fleet,
        **({"run": ctx.cfg.run} if ctx.cfg.run is not None else {}),
    })


def finish_report(ctx: MissionContext) -> None:
    rec = record(ctx)
    if rec is not None:
        cross_check(ctx, rec)
    outcome = verify.outcome(ctx)
    if rec is not None and rec.collisions:
        outcome = "failed"
    fill(ctx, rec, outcome, verify.reason(ctx))
    ctx.clock.lap("report")
    ctx.report["timings"] = ctx.clock.timings
    if ctx.cfg.out is not None:
        report_files.write_outputs(ctx.cfg.out, ctx.report, ctx.frames, ctx.plans.model.free, ctx.plans.first,
                                   ctx.plans.ids)


def abort_report(ctx: MissionContext, reason: str, record_timeout_s: float = world_query.QUERY_TIMEOUT_S) -> None:
    """An aborted mission still leaves its report: completed false, the reason, the events, and the
    robots an image showed on their goals after their last move (verified, whatever came after)."""
    a, plans = ctx.arrivals, ctx.plans
    try:
        if plans.now is not None and not a.verified:
            a.verified = {r: a.confirmed.get(r) == plans.now.plan_id for r in plans.ids}
        rec = record(ctx, record_timeout_s)
        if rec is not None:
            cross_check(ctx, rec)
        fill(ctx, rec, "aborted", reason)
        if ctx.cfg.out is not None:
            report_files.write_report(ctx.cfg.out, ctx.report)
    except Exception as exc:  # noqa: BLE001 - the report must not hide the abort's own error
        ctx.progress.phase("abort", f"could not write the report: {exc}")
