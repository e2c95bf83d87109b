"""The start: the recorders the UAV was told of, the world and its floor, the camera, the
autopilot's link and the watch over it; the planners' kernels get ready meanwhile."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

from protocol.errors import MissionError
from protocol.messages import WorldInfo, WorldInfoRequest

from ..camera_source import open_camera_source
from ..pose_feed import PoseFeed
from ..watch import VehicleWatch
from .. import world_query
from . import context, looks, plan
from .context import MissionContext

OBSERVER_WAIT_S = 5.0      # for the recorders the UAV was told of (MissionConfig.observers); then it goes on
TELEMETRY_HZ = 50.0        # attitude, position and velocity asked of the autopilot (PX4's onboard link streams as fast)


def connect(ctx: MissionContext) -> None:
    from ..flight import Flight
    from ..perception import Landmarks

    cfg = ctx.cfg
    await_observers(ctx)
    # Listening on MAVLink while the world starts: its vehicle's first heartbeat is not lost.
    ctx.flight = Flight(cfg.mavlink_url).open()
    ctx.status("connecting", message="waiting for the world on Zenoh")
    ctx.fleet.wait_until(lambda: ctx.fleet.world_alive, cfg.startup_timeout_s,
                         lambda: f"no world on fleet {cfg.fleet} within {cfg.startup_timeout_s:g} s")
    info = world_query.query(ctx.transport, ctx.keys.world_info, WorldInfoRequest(seq=ctx.next_seq()), WorldInfo, "info")
    check_floor(info)
    ctx.info = info
    ctx.landmarks = Landmarks.from_info(info)
    ctx.camera = open_camera_source(cfg.camera, ctx.transport, ctx.keys, info, ctx.next_seq,
                                    ctx.telemetry_pose, cfg.startup_timeout_s)
    ctx.uav["camera_source"] = cfg.camera.kind
    v = ctx.vantage
    v.calibration = ctx.capture(calibration_only=True)   # the camera's intrinsics and lens
    ctx.frames.clear()
    # The survey's image border needs the lens's full-frame undistortion maps (0.4 s at
    # 12 MP, which the first image's perception then reuses): worked out while the
    # autopilot link comes up, not between arming and the take-off.
    lens = ThreadPoolExecutor(1, thread_name_prefix="lens-border")
    v.border = lens.submit(looks.border, v.calibration, cfg.min_px_per_cell, info.cell_size_m)
    lens.shutdown(wait=False)
    plan.start_warm_up(ctx)
    ctx.flight.connect(timeout_s=cfg.startup_timeout_s)
    for refused in ctx.flight.stream(TELEMETRY_HZ):
        ctx.progress.phase("connect", f"the autopilot keeps its own rate for {refused}")
    ctx.uav["frame"] = "local" if ctx.flight.local_frame else "global"   # indoor: no home, offboard
    ctx.uav["autopilot"] = ctx.flight.autopilot   # PX4, ARDUPILOT, ...: from its heartbeat
    watch = ctx.watch = VehicleWatch(ctx.flight, ctx.vehicle_fault)
    # Every command and every wait of the flight checks it, and every wait for the fleet: the
    # autopilot's own decision wins, and it is noticed within a poll in every phase.
    ctx.flight.guard = watch.now
    ctx.fleet.interrupt = lambda: f"vehicle: {watch.fault}" if watch.fault else None
    ctx.pose_feed = PoseFeed(ctx.flight, lambda p: ctx.transport.put(ctx.keys.uav_pose, context.encode(p)),
                             t0=ctx.events.t0)
    ctx.clock.lap("connect")
    plan.start_interpreter(ctx)


def await_observers(ctx: MissionContext) -> None:
    """A recorder started beside the UAV connects once the UAV listens; whatever the UAV publishes
    before that is lost to it (Zenoh keeps no history), the take-off included."""
    n = ctx.cfg.observers
    if n <= 0:
        return
    fleet = ctx.fleet
    try:
        fleet.wait_until(lambda: len(fleet.observers) >= n, OBSERVER_WAIT_S,
                         lambda: f"{len(fleet.observers)} of {n} observer(s) within {OBSERVER_WAIT_S:g} s")
    except MissionError as exc:
        ctx.progress.phase("connecting", f"not waiting longer for a recorder ({exc}): it may miss the start")


def check_floor(info: WorldInfo) -> None:
    """A floor larger than one survey covers ends the mission before the vehicle flies."""
    from protocol.errors import UavRobotsError
    from scenarios.limits import check_floor as within_limits

    try:
        within_limits(info.width, info.height, "the world's floor")
    except UavRobotsError as exc:
        raise MissionError(str(exc)) from None
