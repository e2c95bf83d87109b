"""Watching the people, forklifts and pallets while the fleet runs (docs/protocol.md, *Movers on
the floor*; docs/movers.md): looks at the floor every few ticks, and before every tick the plan
repaired around the cells a mover may reach by then.

A look is an image taken while the fleet holds after tick k and perceived before tick k + 1 is
sent: its movers are where they were at tick k. What it shows rules movers out of the cells it
saw (`planning/mover_sets.py`: the sets of cells where movers may be, grown by each kind's speed
every tick) and extends the tracks (`planning/forecast.py`: who is who, how fast). The repair
(`planning/avoid.py`) changes only the robots whose next steps meet the forecast, or holds them;
a robot that stays is never touched (no mover steps into a robot's cell), so a hold is always
safe, however long ago a part of the floor was seen.

Where one image from the hover holds the whole floor, the looks are taken from there every
`every` ticks and judged as monitoring images too (arrivals, deviations). A larger floor is
watched from a tour of poses high enough for the movers' colours (WATCH_PX_PER_CELL), one region
per look: the next is the one where the most robots wait for the forecast to clear; when a look
is due the fleet holds until the vehicle is there.
"""
from __future__ import annotations

import secrets
import statistics
import time
from dataclasses import dataclass, field
from typing import Any

from protocol.errors import MissionError

from .context import MissionContext
from .state import PlanState

LOOK_EVERY = 2          # auto, one image holds the floor: a look every this many ticks (docs/movers.md)
LOOK_EVERY_TOUR = 4     # auto, a tour of poses: the fleet waits for a hop and a look every this many ticks
WINDOW = 1              # ticks ahead the forecast is applied: every tick is repaired, so the next step is enough
WATCH_PX_PER_CELL = 8.0  # a tour's resolution: the movers' colours are read at 6.6 px per cell (perception tests)
REACH_POSE_S = 60.0     # the longest wait for the vehicle to reach its next watch pose before looking anyway


@dataclass
class MoverWatch:
    every: int                                   # ticks between looks
    tracker: Any                                 # planning.forecast.Tracker
    sets: Any                                    # planning.mover_sets.MoverSets
    window: int = WINDOW
    poses: list = field(default_factory=list)    # a tour's watch poses (north, east, alt); empty: the hover
    target: int | None = None                    # the tour's pose flown to
    looked: dict[int, int] = field(default_factory=dict)   # tour pose -> the tick of its last look
    waiting: set[int] = field(default_factory=set)          # robots the last repair held or replanned
    last_look: int | None = None                 # the tick of the last look
    looks: int = 0
    look_s: list[float] = field(default_factory=list)
    repairs: int = 0                             # ticks whose plan the repair changed
    replanned: int = 0                           # robot paths changed, in all
    held: int = 0                                # robot-ticks held
    frozen: int = 0                              # ticks every robot was held
    repair_ms: list[float] = field(default_factory=list)
    kinds_seen: set[str] = field(default_factory=set)
    blocked_goals: set[tuple[int, int]] = field(default_factory=set)

    def summary(self) -> dict[str, Any]:
        ms = self.repair_ms or [0.0]
        return {"look_every": self.every, "window": self.window, "tour_poses": len(self.poses), "looks": self.looks,
                "look_s_median": round(statistics.median(self.look_s), 3) if self.look_s else None,
                "tracks": len(self.tracker.tracks), "dropped_tracks": len(self.tracker.dropped),
                "repairs": self.repairs, "replanned": self.replanned, "held_robot_ticks": self.held,
                "frozen_ticks": self.frozen, "repair_ms_median": round(statistics.median(ms), 3),
                "repair_ms_max": round(max(ms), 3),
                "goals_under_movers": sorted(list(g) for g in self.blocked_goals)}


def start(ctx: MissionContext, model, first: PlanState) -> PlanState:
    """After the survey: watch if told to (`--look-every L`), or, by default, once the survey saw a
    mover; the survey's movers (all seen at tick 0: nothing moves before the first tick) start the
    tracks and the sets, and the first plan is repaired around them before it is sent (a robot
    takes a plan of tick 0 only as its first). Returns the plan to send."""
    from ..planning.avoid import warm_up
    from ..planning.forecast import Tracker
    from ..planning.mover_sets import MoverSets

    every = ctx.cfg.look_every
    seen = list(getattr(model, "movers", []))
    if every == 0 or (every is None and not seen):
        return first
    free = _free(ctx)
    poses = _tour(ctx)
    watch = ctx.movers = MoverWatch(every or (LOOK_EVERY_TOUR if poses else LOOK_EVERY), Tracker(free),
                                    MoverSets(free), poses=poses)
    watch.tracker.update(0, seen)
    watch.sets.look(0, seen, model.seen)
    watch.last_look = 0
    watch.kinds_seen = {s.kind for s in seen}
    took = warm_up()
    kinds = ", ".join(f"{sum(s.kind == k for s in seen)} {k}(s)" for k in sorted(watch.kinds_seen)) or "none yet"
    where = f"from a tour of {len(poses)} poses" if poses else "from the hover"
    ctx.event("movers", [], f"the survey saw movers on the floor: {kinds}",
              f"a look every {watch.every} tick(s) {where}; every step checked against where they may be "
              f"(repair kernels ready in {took:.2f} s)")
    ctx.plans.now = first
    around = before_tick(ctx, 0)
    return first if around is None else PlanState(first.plan_id, 0, around.paths, around.goals)


def _tour(ctx: MissionContext) -> list:
    """The watch poses of a floor one image from the hover does not hold: a survey's tiling at the
    movers' resolution (empty when the hover holds the floor)."""
    from ..survey import survey_poses
    from .looks import border

    if len(ctx.vantage.poses) <= 1:
        return []
    camera, info = ctx.vantage.calibration, ctx.info
    poses = survey_poses(info.width, info.height, info.cell_size_m, camera, WATCH_PX_PER_CELL,
                         border_px=border(camera, WATCH_PX_PER_CELL, info.cell_size_m))
    return [tuple(p) for p in poses]     # one, higher than the survey flew, may hold what the hover does not


def _free(ctx: MissionContext):
    """The floor the repair plans on: the perceived one, less the cells of robots out of the plan."""
    free = ctx.plans.free.copy()
    for x, y in ctx.roster.blocked.values():
        free[y, x] = False
    return free


def before_tick(ctx: MissionContext, k: int) -> PlanState | None:
    """Before tick k + 1 (after `look_if_due`): the plan from tick k repaired around the forecast.
    The plan to send when the repair changed it (the caller dispatches it), else None."""
    from ..planning.avoid import repair

    watch = ctx.movers
    if watch is None:
        return None
    plan = ctx.plans.now
    free = _free(ctx)
    paths = {r: [plan.cell(r, t) for t in range(k, max(plan.end_tick, k) + 1)] for r in plan.ids}
    watch.sets.advance(k)
    fc = watch.sets.forecast(k + watch.window)
    rep = repair(free, paths, fc, k, watch.window, ctx.cfg.connectivity)
    watch.repair_ms.append(1e3 * rep.seconds)
    watch.waiting = set(rep.met) | set(rep.held)
    if not (rep.replanned or rep.held or rep.frozen):
        return None
    watch.repairs += 1
    watch.replanned += len(rep.replanned)
    watch.held += len(rep.held) if not rep.frozen else len(plan.ids)
    watch.frozen += rep.frozen
    if rep.frozen:
        ctx.event("movers-hold", sorted(rep.met), f"no way round the movers' forecast after tick {k}",
                  f"the whole fleet holds {watch.window} tick(s)")
    return PlanState(secrets.token_hex(4), k, rep.paths, dict(plan.goals))


def look_if_due(ctx: MissionContext, k: int) -> list[int]:
    """Before tick k + 1: a look if one is due (the fleet holds after tick k meanwhile), or, on a
    tour, whenever the vehicle holds at its watch pose. Returns the robots a look from the hover
    shows off their plan (it is judged as a monitoring image is, arrivals confirmed too)."""
    watch = ctx.movers
    if watch is None:
        return []
    due = watch.last_look is None or k - watch.last_look >= watch.every
    if not watch.poses:
        return look(ctx, k) if due else []
    from .looks import still_at

    if watch.target is None:
        _fly_on(ctx, k)
    pose = watch.poses[watch.target]
    if due:
        deadline = time.monotonic() + REACH_POSE_S
        while not still_at(ctx, pose) and time.monotonic() < deadline:
            ctx.check_vehicle()
            if ctx.interrupted():
                raise MissionError("interrupted while the vehicle flew to its watch pose")
            time.sleep(0.02)
    elif not still_at(ctx, pose):
        return []
    look(ctx, k, movers_only=True)
    watch.looked[watch.target] = k
    _fly_on(ctx, k)
    return []


def _fly_on(ctx: MissionContext, k: int) -> None:
    """The tour's next pose: the one over the most robots the last repair held or sent round a
    forecast (the cells only a look can clear), then over the most robots still on their way, the
    one looked at longest ago first; the vehicle flies there at once."""
    from ..survey import nearest_pose

    watch, plan, c = ctx.movers, ctx.plans.now, ctx.info.cell_size_m
    waiting = [0] * len(watch.poses)
    moving = [0] * len(watch.poses)
    for r in plan.ids:
        here = plan.cell(r, k)
        i = nearest_pose(watch.poses, here, c)
        waiting[i] += r in watch.waiting
        moving[i] += here != tuple(plan.goals[r])
    options = [i for i in range(len(watch.poses)) if i != watch.target] or [0]
    watch.target = max(options, key=lambda i: (waiting[i], moving[i] > 0, k - watch.looked.get(i, -1)))
    ctx.flight.go(*watch.poses[watch.target])


def look(ctx: MissionContext, k: int, movers_only: bool = False) -> list[int]:
    """An image now (the fleet holds after tick k): what it shows rules movers in and out of the
    cells it saw; unless `movers_only`, judged as a monitoring image (the robots off their plan)."""
    from .monitor import arrived_by, judged, taken_in
    from .state import Glance

    watch = ctx.movers
    t = time.perf_counter()
    frame = ctx.capture()
    fusion = ctx.fusion(set(ctx.plans.ids))
    fusion.add(frame, movers_only=movers_only)
    shown, checked = fusion.last_movers, fusion.last_checked
    update = watch.tracker.update(k, shown, checked)
    watch.sets.look(k, shown, checked)
    watch.last_look = k
    watch.looks += 1
    watch.look_s.append(time.perf_counter() - t)
    ctx.clock.add("mover_looks", time.perf_counter() - t)
    new = {s.kind for s in shown} - watch.kinds_seen
    if new:
        watch.kinds_seen |= new
        ctx.event("movers", [], f"a look after tick {k} saw a kind of mover not seen before: {', '.join(sorted(new))}")
    if update.dropped:
        ctx.event("mover-lost", [], f"{len(update.dropped)} mover(s) not seen in two looks that covered where they "
                  f"could be, after tick {k}", "their tracks are dropped until seen again")
    if movers_only:
        return []
    ctx.arrivals.monitored += 1
    plan = ctx.plans.now
    return taken_in(ctx, judged(Glance(plan.plan_id, k), fusion.model(), plan, arrived_by(ctx, k)))


def goals_lost(ctx: MissionContext, k: int) -> list[int]:
    """Robots whose goal a pallet now lies on: a pallet stays, so the goal cannot be served. Each is
    taken out of the plan where it stands (quarantined: not for a fault of its own, but it has no
    goal left: every other goal is another robot's), its goal reported unserved; the caller repairs
    the plan without them, so that no robot waits for ever in front of it."""
    from .repair import quarantine

    watch, plan = ctx.movers, ctx.plans.now
    if watch is None:
        return []
    pallets = {tr.cell for tr in watch.tracker.tracks.values() if tr.kind == "pallet"}
    out = []
    for r in plan.ids:
        goal = tuple(plan.goals[r])
        if goal in pallets and plan.cell(r, k) != goal and r not in ctx.roster.blocked:
            watch.blocked_goals.add(goal)
            model = ctx.plans.model
            model.goals = [g for g in model.goals if tuple(g) != goal]
            ctx.event("goal-under-mover", [r], f"a pallet lies on robot {r}'s goal {goal} (seen by tick {k})",
                      "the goal is reported unserved")
            quarantine(ctx, r, f"its goal {goal} lies under a pallet", plan.cell(r, k))
            out.append(r)
    return out


def report(ctx: MissionContext) -> dict[str, Any]:
    return {"mover_watch": ctx.movers.summary()} if ctx.movers is not None else {}


def unserved(ctx: MissionContext) -> list:
    """The goals left unserved: the last repair's, and those a pallet lies on."""
    lost = sorted(ctx.movers.blocked_goals) if ctx.movers is not None else []
    return [tuple(g) for g in ctx.plans.unserved] + [g for g in lost if g not in {tuple(u) for u in ctx.plans.unserved}]
