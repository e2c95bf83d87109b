"""Watching the fleet while it moves: arrival stops flown between ticks, monitoring images taken
while the vehicle holds still and perceived off the tick loop, and what they show: robots off
their planned cells (a deviation), robots on their goals after their last move (an arrival)."""
from __future__ import annotations

import math
import time

from protocol.grid import Cell
from protocol.messages import CameraFrame

from . import looks
from .context import MissionContext
from .state import Glance, PlanState

MONITOR_FIRST = 25         # auto monitoring: the first image after this many ticks ...
MONITOR_SHARE = 0.2        # ... then whenever the images so far cost at most this share of execution time
MAX_GLANCES = 3            # monitoring images perceived at once, off the tick loop (each holds a full frame)


def plan_stops(ctx: MissionContext, plan: PlanState) -> None:
    """Where to confirm the arrivals of `plan` while it runs. A confirmation under an earlier
    plan stands for a robot the new one leaves on its goal."""
    from ..arrival_tour import arrival_ticks, stops

    a = ctx.arrivals
    a.confirmed = {r: plan.plan_id for r in a.confirmed if r in plan.paths
                   and {tuple(c) for c in plan.paths[r]} == {tuple(plan.goals[r])}}
    todo = {r: tuple(plan.goals[r]) for r in plan.ids if r not in a.confirmed}
    a.ticks = arrival_ticks(plan.paths, plan.start_tick)   # of the plan flown: robot -> its last move's tick
    # Watching movers, the vehicle holds where it looks from: arrivals are confirmed by the looks and the verification.
    a.stops = stops(ctx.vantage.poses, todo, a.ticks, ctx.info.cell_size_m) if todo and ctx.movers is None else []
    a.stop = None


def between_ticks(ctx: MissionContext, k: int) -> None:
    """Between tick k and the next: the image due now, if any (an arrival stop reached once its
    robots have made their last moves; monitoring while the vehicle holds still), and where
    the vehicle flies next. Nothing is shot from a moving vehicle, and the vehicle flies on
    as soon as the shutter has opened."""
    from ..arrival_tour import next_stop

    a, v = ctx.arrivals, ctx.vantage
    stop = a.stop
    if stop is not None and not looks.still_at(ctx, stop.pose):
        return
    if stop is not None and v.hop is not None:   # arrived: plan with the speed hops really make
        began, metres = v.hop
        v.hop = None
        v.flew(metres, time.perf_counter() - began)
    if stop is not None and k >= stop.ready_tick and len(a.glances) < MAX_GLANCES:
        shoot(ctx, k, stop)
        a.stops.remove(stop)
        stop = a.stop = None
    elif not a.glances and due(ctx, k):
        shoot(ctx, k)
    if stop is None and a.stops:
        ran = time.perf_counter() - a.exec_t0
        tick_s = ran / (k - a.exec_k0) if k - a.exec_k0 >= 10 else 0.05
        here = ctx.flight.position_ned()
        stop = a.stop = next_stop(a.stops, (here[0], here[1]), k, tick_s, v.speed_m_s)
        ctx.flight.go(*stop.pose)
        v.hop = (time.perf_counter(), math.dist((here[0], here[1]), stop.pose[:2]))


def last_looks(ctx: MissionContext) -> None:
    """The images that end execution: those still being perceived, then the arrival stop the
    vehicle holds at. A deviation they show, the verification's look sees too."""
    a = ctx.arrivals
    seen(ctx, wait=True)
    stop = a.stop
    if stop is not None and ctx.tick >= stop.ready_tick and looks.still_at(ctx, stop.pose):
        shoot(ctx, ctx.tick, stop)
        a.stops.remove(stop)
        a.stop = None
        seen(ctx, wait=True)


def taken_in(ctx: MissionContext, g: Glance) -> list[int]:
    """A judged image's findings taken in, if it was taken under the plan flown now: its arrivals
    confirmed, strikes forgiven for robots it shows on plan; the robots it shows off their plan."""
    if g.plan_id != ctx.plans.now.plan_id:
        return []
    ctx.arrivals.confirmed.update((r, g.plan_id) for r in g.on_goal)
    if ctx.roster.strikes:
        ctx.roster.forgive(g.on_plan)
    if g.off:
        ctx.event("camera-deviation", g.off, f"seen off its planned cell after tick {g.tick}")
    return list(g.off)


def due(ctx: MissionContext, k: int) -> bool:
    a = ctx.arrivals
    if ctx.movers is not None:   # the movers' looks, every tick or two, are the monitoring
        return False
    every = ctx.cfg.monitor_every
    if every is not None:
        return every > 0 and k % every == 0
    # Auto: the images' work (render, send, perceive: off the tick loop, but on the same cores)
    # may take at most MONITOR_SHARE of the execution time. An image costs what the last one
    # did, so the next is due once the time since execution began is that large.
    if k < MONITOR_FIRST:
        return False
    spent = a.monitor_work
    last = spent / a.monitored if a.monitored else 0.0
    running = time.perf_counter() - a.exec_t0
    return (spent + last) <= MONITOR_SHARE * running


def shoot(ctx: MissionContext, k: int, stop=None) -> None:
    """Take one image from where the UAV holds (at `stop`, if one) while the fleet holds after
    tick k, and go on: the fleet holds only until the shutter has opened; the image is
    perceived meanwhile, and `seen` reports the robots it shows off their planned cell
    at tick k and confirms those it shows on their goals after their last move. Robots outside
    the image are not checked until the next full look."""
    t = time.perf_counter()
    a, plan = ctx.arrivals, ctx.plans.now
    fusion = ctx.fusion(set(plan.ids))
    arrived = arrived_by(ctx, k)
    glance = Glance(plan.plan_id, k)

    def judge(frame: CameraFrame) -> None:   # on the images' thread
        fusion.add(frame)
        glance.took = time.perf_counter() - t
        judged(glance, fusion.model(), plan, arrived)

    roi = None
    if stop is not None:
        roi = region(ctx, stop.pose, [tuple(plan.goals[r]) for r in sorted(stop.robots) if r in plan.goals])
    glance.shots = ctx.shots(fusion, whole=judge, roi=roi)
    a.glances.append(glance)
    glance.shots.shoot(None if stop is None else stop.pose)
    ctx.clock.add("monitor", time.perf_counter() - t)
    a.monitored += 1


def arrived_by(ctx: MissionContext, k: int) -> set[int]:
    """The robots whose last move of the plan flown is at or before tick k."""
    return {r for r, tick in ctx.arrivals.ticks.items() if tick <= k}


def judged(glance: Glance, model, plan: PlanState, arrived: set[int]) -> Glance:
    """What an image taken after `glance.tick` shows of `plan`, the one it was taken under: robots on
    their planned cell, off it, and (of the `arrived`) on their goals after their last move."""
    k = glance.tick
    glance.on_goal = [r for r, c in model.robots.items() if r in arrived and tuple(c) == tuple(plan.goals[r])]
    glance.on_plan = [r for r, c in model.robots.items() if r in plan.paths and tuple(c) == plan.cell(r, k)]
    glance.off = sorted(r for r, c in model.robots.items() if r in plan.paths and tuple(c) != plan.cell(r, k))
    return glance


def region(ctx: MissionContext, pose, cells: list[Cell]):
    """The sensor region an arrival stop's image from `pose` needs to show `cells` (its robots'
    goals): those cells and the landmarks around them (`region.py`); None for the whole image
    (no cells, or a region nearly as large). The verification's look after
    the last tick takes whole images: what a region missed, it sees."""
    from ..region import region_for

    if not cells:
        return None
    camera, c = ctx.vantage.calibration, ctx.info.cell_size_m
    ppc = min(camera.fx, camera.fy) * c / max(pose[2], 1e-6)
    return region_for(cells, camera, pose, c, ctx.landmarks, max(looks.border(camera, ppc, c)),
                      (ctx.info.width, ctx.info.height))


def seen(ctx: MissionContext, wait: bool = False) -> list[int]:
    """The robots the monitoring images perceived since the last call (all of them, if `wait`)
    show off the plan they were judged against, if it is still the one flown; the arrivals
    they show are confirmed, and the stops left with nothing to confirm dropped."""
    a, plan = ctx.arrivals, ctx.plans.now
    off: set[int] = set()
    while a.glances and (wait or a.glances[0].shots.done()):
        g = a.glances.pop(0)
        try:
            g.shots.drain()
        finally:
            g.shots.close()
        if g.off is None:   # the image missed its pose: no judgement
            continue
        a.monitor_work += g.took
        off.update(taken_in(ctx, g))
    pid = plan.plan_id
    a.stops = [s for s in a.stops if not all(a.confirmed.get(r) == pid for r in s.robots)]
    if a.stop not in a.stops:
        a.stop = None
    return sorted(off)
