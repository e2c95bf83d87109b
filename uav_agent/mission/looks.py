"""How the UAV looks at the floor: a level airframe before each shutter, a tour of poses with
the images perceived on the way, retakes, and closer looks at whatever stays in doubt. The
survey, the monitoring, a repair's fresh look and the verification all look this way."""
from __future__ import annotations

import math
import time

from protocol.errors import MissionError
from protocol.grid import Cell
from protocol.messages import CameraFrame

from .config import MissionConfig
from .context import MissionContext

LEVEL_TILT_DEG = 0.6       # a shutter (survey, fresh look, closer look) waits for the body, and its camera, this level ...
LEVEL_WAIT_S = 3.0         # ... for at most this long: a vehicle that has just braked hangs at its tilt limit
SURVEY_BORDER_PX = 8       # pixels at each image's edge the survey never counts on, beyond the lens, tilt and hold
HOVER_TOLERANCE_M = 0.5    # a goto has arrived within this (Flight.goto's default)


def border(camera: CameraFrame, px_per_cell: float = MissionConfig.min_px_per_cell,
           cell_size_m: float = 1.0) -> tuple[int, int]:
    """Pixels (left and right, top and bottom) of each image the survey does not count on:
    where the lens leaves the undistorted image empty; how far a tilt the shutter accepts
    (LEVEL_TILT_DEG: a body-fixed camera, a hover wobble) swings the footprint's edges
    (`survey.tilt_margin_px`, at any altitude); and how far the vehicle may hold from its
    pose (the hover tolerance, sideways and in height: about as many pixels as it is metres
    times the survey's pixels per metre, each)."""
    from ..perception.frames import lens_margin_px
    from ..survey import tilt_margin_px

    tilt = tilt_margin_px(camera, math.radians(LEVEL_TILT_DEG))
    base = SURVEY_BORDER_PX + lens_margin_px(camera) + math.ceil(2 * HOVER_TOLERANCE_M * px_per_cell / cell_size_m)
    return base + tilt[0], base + tilt[1]


def hold_level(ctx: MissionContext) -> None:
    """Wait, briefly, for the airframe to level out: a camera fixed to the body sees the floor
    through its tilt, and a vehicle that has just stopped still leans by up to its tilt limit
    (20 degrees swings an image's footprint by a third of the altitude)."""
    deadline = time.monotonic() + LEVEL_WAIT_S
    arrived = ctx.flight.attitude_sample()[3]
    while time.monotonic() < deadline and not level_since(ctx, arrived):
        time.sleep(0.02)


def level_since(ctx: MissionContext, arrived: int) -> bool:
    """Level by an attitude sample sent after `arrived` (the time of the one current when the
    vehicle was seen to arrive; 0 from an autopilot that times none). The one read with the
    arrival may have been sent before it, while the vehicle cruised level at constant speed:
    only a later one shows it braking (a survey image was shot leaning 20 degrees)."""
    roll, pitch, _, stamp = ctx.flight.attitude_sample()
    return (stamp != arrived or not stamp) and math.hypot(roll, pitch) <= math.radians(LEVEL_TILT_DEG)


def still_at(ctx: MissionContext, pose) -> bool:
    """Settled at `pose` and level, by an attitude sample sent after the arrival was seen (see
    `level_since`)."""
    a = ctx.arrivals
    if not ctx.flight.settled_at(*pose):
        a.arrived_at = None
        return False
    if a.arrived_at is None:
        a.arrived_at = ctx.flight.attitude_sample()[3]
    return level_since(ctx, a.arrived_at)


def budget(ctx: MissionContext, poses, what: str) -> None:
    """Fly `poses` only if the battery holds them and the landing after, with a reserve."""
    from ..budget import flight_seconds, shortfall

    n, e, d = ctx.flight.position_ned()
    why = shortfall(ctx.flight.battery_time_left_s, flight_seconds(list(poses), (n, e, -d)), what,
                    ctx.flight.battery_pct)
    if why:
        raise MissionError(why)


def tour(ctx: MissionContext, poses, fusion) -> None:
    """Fly over `poses` (north, east, alt), taking an image at each without waiting for it;
    every image is perceived into `fusion` by the time this returns."""
    budget(ctx, poses, f"a look of {len(poses)} image(s)")
    shots = ctx.shots(fusion)
    try:
        for north, east, alt in poses:
            ctx.flight.goto(north, east, alt)
            hold_level(ctx)
            shots.shoot((north, east, alt))
        shots.drain()
    finally:
        shots.close()
    retake(ctx, shots, fusion)


def retake(ctx: MissionContext, shots, fusion) -> None:
    """Take again, holding still until each arrives, the images the vehicle flew away from
    or shot leaning."""
    if shots.missed:
        ctx.event("retake", [], f"{len(shots.missed)} image(s) not used: " + "; ".join(
            f"{why} at ({n:.1f}, {e:.1f}, {a:.1f})" for why, (n, e, a) in zip(shots.why_missed, shots.missed)),
            "holding still over each pose for a new image")
    for north, east, alt in shots.missed:
        ctx.flight.goto(north, east, alt)
        hold_level(ctx)
        fusion.add(ctx.capture())
    if shots.missed:
        ctx.uav["retaken_images"] = ctx.uav.get("retaken_images", 0) + len(shots.missed)
        ctx.flight.goto(*ctx.vantage.hover)


def see(ctx: MissionContext, fusion, for_map: bool = True, expected: set[int] | None = None):
    """The model of what `fusion` holds; what it leaves in doubt gets closer looks: markers
    whose id did not decode, unsure cells (before they are taken for obstacles), cells no image
    saw, and, when fewer goals than robots were seen, the robots (one may stand on a goal and
    hide most of it). Every doubtful cell is planned for; the hovers per round are capped.
    `expected`: the robots whose absence is a doubt (default the fusion's known robots: a
    verification's look over some goals does not miss the robots confirmed elsewhere, and
    on a floor of lone obstacles each would cost a round of closer looks)."""
    from ..perception.relook import ROUNDS, plan_round

    v = ctx.vantage
    known = fusion.known_ids if expected is None else expected
    model = fusion.model()
    for attempt in range(1, ROUNDS + 1):
        here = ctx.flight.position_ned()
        targets, hovers = plan_round(model, known, for_map, attempt, v.alt, ctx.info.cell_size_m,
                                     v.calibration, ctx.landmarks, (here[0], here[1]),
                                     math.radians(LEVEL_TILT_DEG), len(v.poses))
        if not targets:
            break
        heights = sorted({round(alt, 1) for _, _, alt in hovers})
        # An event, not only a progress line: a closer look costs seconds, and the report says why.
        missing = sorted(set(known or ()) - set(model.robots))
        ctx.event("closer-look", missing,
                  f"{len(targets)} cell(s) in doubt: {model.unseen} unseen, {len(model.unidentified)} unreadable "
                  f"marker(s){f' at {model.unidentified[:5]}' if model.unidentified else ''}, {len(model.unsure)} "
                  f"unsure{f' at {model.unsure[:5]}' if model.unsure else ''}, {len(model.robots)} robots / "
                  f"{len(model.goals)} goals seen",
                  f"{len(hovers)} hover(s) at {heights} m (round {attempt})")
        tour(ctx, hovers, fusion)
        model = fusion.model()
        ctx.flight.goto(*v.hover)
    return model


def look(ctx: MissionContext, cells: list[Cell] | None = None, back: bool = True,
         expected: set[int] | None = None) -> dict[int, Cell]:
    """A fresh look from the survey poses, at the whole floor or only at the poses that
    see `cells`, then `back` to the hover: robot id -> the cell the camera sees it on.
    `expected`: the robots the look is for (default every robot); only their absence calls
    for closer looks."""
    from ..arrival_tour import Stop, route
    from ..survey import covering, nearer_end_first

    v = ctx.vantage
    here = ctx.flight.position_ned()
    if cells is None:   # the whole survey: its lawn-mower order is the short one
        poses = nearer_end_first(v.poses, (here[0], here[1]))
    else:
        held = covering(v.poses, cells, ctx.info.cell_size_m)
        poses = [s.pose for s in route([Stop(p, 0, frozenset()) for p in held], (here[0], here[1]),
                                       0, 0.0, v.speed_m_s)]
    fusion = ctx.fusion(set(ctx.plans.ids))
    tour(ctx, poses, fusion)
    if back:
        ctx.flight.goto(*v.hover)
    model = see(ctx, fusion, for_map=False, expected=expected)
    return {r: tuple(c) for r, c in model.robots.items()}


def closer_at_goals(ctx: MissionContext, goals: dict[int, Cell]) -> dict[int, Cell]:
    """Robots that raised Done but that the verification's look saw nowhere: their goals once
    more from half the height, as the survey looks closer at what it could not read (a robot
    parked on its goal shows its marker inside the pad's green frame, which a blurred camera
    reads less often than one on bare floor). The robots that look sees, where it sees them."""
    from ..perception.relook import detail_hovers

    v = ctx.vantage
    here = ctx.flight.position_ned()
    hovers = detail_hovers(sorted(set(goals.values())), 1, v.alt, ctx.info.cell_size_m, v.calibration,
                           ctx.landmarks, (here[0], here[1]), math.radians(LEVEL_TILT_DEG), len(v.poses))
    ctx.event("closer-look", sorted(goals), "raised Done, seen nowhere by the verification's look",
              f"{len(hovers)} hover(s) at {sorted({round(a, 1) for _, _, a in hovers})} m over their goals")
    fusion = ctx.fusion(set(ctx.plans.ids))   # the whole codebook: a neighbour's marker is not taken for theirs
    tour(ctx, hovers, fusion)
    return {r: tuple(c) for r, c in fusion.model().robots.items() if r in goals}
