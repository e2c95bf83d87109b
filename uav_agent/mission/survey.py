"""The survey phase: arm, climb, fly the survey's poses with the images perceived on the way
(lower if the camera blurs), hover over the floor's centre; then perceive the floor's model."""
from __future__ import annotations

import math
import threading
import time
from typing import Any

from protocol.errors import MissionError
from protocol.messages import CameraFrame

from . import looks
from .context import MissionContext
from .state import SURVEY_SPEED_M_S

# An autopilot may refuse to arm while it gets ready (ArduPilot SITL: about 38 s after it starts).
ARM_WAIT_S = 60.0
# A heading further than this from north after the first goto: the autopilot does not fly a goto's yaw.
HEADING_TOLERANCE_DEG = 3.0
HANDOFF_ALT_M = 10.0       # take-off to this height, clear of anything on the floor, then on to the first pose
STARTUP_LONGEST = 4        # robots still coming up extend the start-up wait, to this many times it


def fly(ctx: MissionContext) -> None:
    from ..survey import path_length, survey_poses

    cfg, info, v, flight = ctx.cfg, ctx.info, ctx.vantage, ctx.flight
    ctx.status("takeoff", message=f"arming and climbing over MAVLink ({cfg.mavlink_url})")
    flight.arm(ARM_WAIT_S, on_wait=lambda why: ctx.progress.phase(
        "takeoff", f"the autopilot is not ready to arm yet, asking again: {why}"))
    ctx.uav["armed"] = True
    first = v.calibration
    poses = v.poses = survey_poses(info.width, info.height, info.cell_size_m, first,
                                   min_px_per_cell=cfg.min_px_per_cell, border_px=v.border.result())
    ctx.pose_feed.flying(True)
    # A take-off climbs straight up (PX4's does); the rest of the climb is flown on the way to
    # the first pose, the vehicle climbing and crossing at once.
    # Watched from the climb on: a failsafe or a ground station may take the vehicle at once.
    ctx.watch.expect_airborne(True, taking_off=True)
    flight.takeoff(min(poses[0][2], HANDOFF_ALT_M))
    # In the air, the autopilot's estimate is of a hover's draw, not the ground's.
    looks.budget(ctx, poses, f"the survey of {len(poses)} image(s)")
    try:
        flight.set_speed(SURVEY_SPEED_M_S)
    except MissionError as exc:   # an autopilot without DO_CHANGE_SPEED flies its cruise speed
        ctx.progress.phase("survey", f"keeping the vehicle's cruise speed: {exc}")
    flight.goto(*poses[0])
    poses = v.poses = turned(ctx, poses)
    ctx.track_altitude()
    ctx.clock.lap("takeoff")
    # The images are perceived while the vehicle flies on. The first one also measures the
    # camera's blur: if the survey's height is too high to read markers through it, the
    # poses still ahead are dropped for a lower survey.
    v.fusion = ctx.fusion()
    verdict: dict[str, Any] = {}
    t_survey = time.perf_counter()

    judging = threading.Lock()

    def measure(frame: CameraFrame):   # on the images' threads, the fusion merges in order
        from ..perception.frames import pixels

        seen = pixels(frame)        # decoded and undistorted once, for the blur check and the fusion
        with judging:
            judge = "judged" not in verdict
            verdict["judged"] = True
        if judge:
            verdict["lower"] = sharp_enough(ctx, seen.gray, first)
        return v.fusion.measure(seen)

    shots = ctx.shots(v.fusion, measure)
    try:
        for i, (north, east, alt) in enumerate(poses):
            if verdict.get("lower") is not None:
                break
            ctx.status("survey", message=f"image {i + 1}/{len(poses)} from {alt:.1f} m")
            flight.goto(north, east, alt)
            ctx.track_altitude()
            looks.hold_level(ctx)
            shots.shoot((north, east, alt))
        shots.drain(first=1)
        lower = verdict.get("lower")
        if lower is not None:   # the first image was too blurred for the planned height: the lower survey
            poses = v.poses = lower
            for i, (north, east, alt) in enumerate(poses):
                ctx.status("survey", message=f"image {i + 1}/{len(poses)} from {alt:.1f} m "
                                             "(lower: blurred camera)")
                flight.goto(north, east, alt)
                ctx.track_altitude()
                looks.hold_level(ctx)
                shots.shoot((north, east, alt))
        # Hover over the floor's centre while the robots move: the leader keeps them in view.
        c = info.cell_size_m
        centre_n, centre_e = -info.height * c / 2, info.width * c / 2
        v.alt = max(p[2] for p in poses)
        v.hover = (centre_n, centre_e, v.alt) if len(poses) > 1 else poses[-1]
        # Perception's backlog is the survey's only wait: the vehicle flies on to the hover
        # meanwhile, and through perception, planning and dispatch (it must be there only when
        # the robots start moving, see `dispatch.reach_hover`).
        flight.go(*v.hover)
        shots.drain()
    finally:
        shots.close()
    looks.retake(ctx, shots, v.fusion)
    took = time.perf_counter() - t_survey
    if took > 0:
        v.flew(path_length(poses, poses[0][:2]), took)
    ctx.clock.lap("survey")


def sharp_enough(ctx: MissionContext, gray, camera: CameraFrame):
    """None if the survey's resolution reads markers through the blur of this (undistorted,
    grey) image; else the survey poses at the resolution that does (measured from the image's
    own edges)."""
    from ..perception.blur import blur_sigma
    from ..survey import ROBOT_MODULE_CELLS, heading_border, px_per_cell_for, survey_poses

    cfg, info = ctx.cfg, ctx.info
    sigma = blur_sigma(gray)
    c = info.cell_size_m
    module = ROBOT_MODULE_CELLS if ctx.landmarks is None else min(ROBOT_MODULE_CELLS, ctx.landmarks.module_m / c)
    need = px_per_cell_for(sigma, cfg.min_px_per_cell, module)
    ctx.uav["survey_blur_px"] = round(sigma, 2)
    if need <= cfg.min_px_per_cell:
        return None
    ctx.uav["survey_px_per_cell"] = round(need, 1)
    ctx.progress.phase("survey", f"the camera blurs by {sigma:.1f} px: surveying at {need:.0f} px per cell "
                                 f"instead of {cfg.min_px_per_cell:g}")
    return survey_poses(info.width, info.height, c, camera, min_px_per_cell=need,
                        border_px=heading_border(camera, looks.border(camera, need, c), ctx.vantage.heading))


def turned(ctx: MissionContext, poses):
    """The survey's poses again if the autopilot kept another heading than the goto's north (ArduCopter
    ignores a goto's yaw): the footprints are turned, so each tile is what a turned image surely holds."""
    from ..survey import heading_border, survey_poses

    v = ctx.vantage
    heading = math.remainder(ctx.flight.pose()[3], 2 * math.pi)
    if abs(heading) <= math.radians(HEADING_TOLERANCE_DEG):
        return poses
    v.heading = heading
    again = survey_poses(ctx.info.width, ctx.info.height, ctx.info.cell_size_m, v.calibration,
                         min_px_per_cell=ctx.cfg.min_px_per_cell,
                         border_px=heading_border(v.calibration, v.border.result(), heading))
    ctx.uav["heading_kept_deg"] = round(math.degrees(heading), 1)
    ctx.progress.phase("survey", f"the autopilot keeps its heading of {math.degrees(heading):.0f} deg (a "
                                 f"goto's yaw is not flown): {len(again)} turned footprint(s) instead of "
                                 f"{len(poses)}")
    return again


def perceive(ctx: MissionContext):
    """The floor's model from the survey's images, closer looks at what stays in doubt included."""
    from ..perception.verdict import raise_if_missing

    # The robots on the network name the ids the camera may see; a marker read as any
    # other id is a misread, not a robot.
    cfg, fleet = ctx.cfg, ctx.fleet
    expected = cfg.robots
    if expected is not None:
        wait = cfg.startup_timeout_s
        fleet.wait_until(lambda: len(fleet.alive) >= expected, wait,
                         lambda: f"only {len(fleet.alive)} of {expected} robots came alive "
                                 f"(none more for {wait:g} s): robots "
                                 f"{sorted(set(range(expected)) - fleet.alive)[:10]} missing",
                         progress=lambda: len(fleet.alive), longest=STARTUP_LONGEST * wait)
    with fleet.cv:
        known = set(fleet.alive) or None
    ctx.status("perceive", message=f"{len(ctx.frames)} image(s) through OpenCV")
    ctx.vantage.fusion.known_ids = known
    model = looks.see(ctx, ctx.vantage.fusion)
    ctx.perception_warnings = model.warnings
    ctx.perception_frames = model.frames
    raise_if_missing(model, known, expected)
    ctx.plans.model = model
    ctx.clock.lap("perceive")
    return model
