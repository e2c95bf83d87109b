"""`uav-robots world` and `python -m sim_world`: the world process's options and its command."""
from __future__ import annotations

import argparse
from typing import Any

from protocol.config import add_session_arguments
from protocol.errors import MissionError, UavRobotsError
from protocol.faults import CATALOGUE, WORLD
from protocol.keys import DEFAULT_FLEET
from protocol.run_spec import add_spec_argument, apply_spec
from scenarios.scene import add_mover_arguments, scene_of_args

from .camera.model import DEFAULT_CAMERA_PRESET, camera_model_from, camera_options, camera_preset
from .config import DRONE_CAMERA, HOME, MOVE_BATCH_TIMEOUT_S, WorldConfig
from .faults import world_faults
from .service import World
from .vehicle.config import WOBBLE_OF_CAMERA_PRESET
from .vehicle_cli import DEFAULT_URL as DEFAULT_VEHICLE_URL
from .vehicle_cli import add_ground_station_arguments, parse_home


def add_world_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("world", help="run the simulated world: floor, robots' physics, vehicle, camera",
                              description="Serve the simulated warehouse (moves, camera, record) on Zenoh "
                                          "and fly a simulated multicopter over MAVLink.")
    add_world_arguments(p)
    p.set_defaults(func=world_command)
    return p


def add_world_arguments(p: argparse.ArgumentParser) -> None:
    from scenarios.maps import MAP_HELP

    p.add_argument("--map", default="warehouse-small", help=MAP_HELP)
    p.add_argument("--robots", type=int, default=8, help="number of robots (and goals)")
    p.add_argument("--seed", type=int, default=0, help="seed of the placement of robots and goals")
    p.add_argument("--scen", default=None, metavar="FILE", help="take starts and goals from a MovingAI .scen")
    p.add_argument("--fleet", default=DEFAULT_FLEET, help=f"fleet name: keys live under uavr/<fleet> (default {DEFAULT_FLEET})")
    add_session_arguments(p)
    p.add_argument("--mavlink", default=None, metavar="URL",
                   help=f"the vehicle's MAVLink link (pymavlink URL; default {DEFAULT_VEHICLE_URL}); 'none' runs "
                        "without a vehicle")
    add_ground_station_arguments(p)
    p.add_argument("--autopilot-pose", default=None, metavar="URL",
                   help="fly no vehicle: follow the autopilot whose telemetry comes on this link (its ground "
                        "station's port: `uav-robots vehicle --pose-link`, PX4 or ArduPilot SITL, a real drone) "
                        "and render the camera from its pose, e.g. udpin:127.0.0.1:14550")
    p.add_argument("--autopilot-origin", default=None, metavar="home|N,E,D",
                   help="with --autopilot-pose, where the autopilot's local frame lies: 'home' (default: its "
                        "first home is the floor's top-left corner) or its local origin's N,E,D on the floor "
                        "(metres; an indoor autopilot without GPS)")
    p.add_argument("--time-scale", type=float, default=1.0, metavar="X", help="simulated seconds per second")
    p.add_argument("--cell-size", type=float, default=1.0, metavar="M", help="grid cell size in metres")
    p.add_argument("--connectivity", type=int, choices=(4, 8), default=4)
    p.add_argument("--home", default=None, metavar="LAT,LON,ALT", help="the grid corner's geodetic position")
    p.add_argument("--camera", default="", metavar="[PRESET,]K=V,...",
                   help="the camera: a preset (ideal, realistic; default "
                        f"{DEFAULT_CAMERA_PRESET}) then keys over it, on the 12 MP drone camera (4000x3000, "
                        "90 deg), e.g. realistic,blur_sigma=2 or width=1280,height=960,noise_std=2 "
                        "(every key: docs/camera-and-perception.md)")
    p.add_argument("--scene", default="", metavar="[PRESET,]K=V,...",
                   help="what the world lays on the floor for the camera: a preset (ideal, realistic) then keys "
                        "over it, landmark_spacing=N (cells; 0 none) and goal_pads=0|1 (default: the camera "
                        "preset's namesake)")
    add_mover_arguments(p)
    p.add_argument("--wobble", type=float, default=None, metavar="DEG",
                   help="its vehicle's roll and pitch wobble in a hover, degrees (default: 0.3 with the realistic "
                        "camera, 0 with the ideal one)")
    p.add_argument("--camera-mavlink", default=None, metavar="URL",
                   help="also a MAVLink camera component (Camera Protocol v2) on a link of its own, e.g. "
                        "udpout:127.0.0.1:14560; its images served over HTTP on --mavlink-bind")
    p.add_argument("--camera-video", default=None, metavar="udp://HOST:PORT[?fps=F&width=W]",
                   help="stream the camera's video as H.264 over RTP to HOST:PORT (QGroundControl: 5600; "
                        "default 5 fps, 1280 px wide); off by default (it costs the world CPU)")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help="inject a fault into the world (repeatable): " + "; ".join(
                       f"{k.form}: {k.help}" for k in CATALOGUE if k.injector == WORLD))
    p.add_argument("--move-timeout", type=float, default=MOVE_BATCH_TIMEOUT_S, metavar="S",
                   help="how long a tick's moves are collected before the missing robots are made to stay")
    add_spec_argument(p)


# What the world takes from a run's spec (`--spec OUT/run.json`): the floor, the placement, the camera and
# the world's own faults.
SPEC_FIELDS = {
    "--map": lambda s: s.map, "--robots": lambda s: s.robots, "--seed": lambda s: s.seed,
    "--connectivity": lambda s: s.planning.connectivity, "--time-scale": lambda s: s.vehicle.time_scale,
    "--camera": lambda s: s.camera.model, "--mavlink-bind": lambda s: s.vehicle.mavlink_bind,
    "--scen": lambda s: s.scen, "--scene": lambda s: s.scene.text(), "--wobble": lambda s: s.vehicle.wobble_deg,
    "--fault": lambda s: s.faults_for(WORLD),
}


def _none(url: str | None) -> str | None:
    return None if url is None or url.lower() in ("none", "off", "") else url


def config_from_args(args: argparse.Namespace) -> WorldConfig:
    from .pose_follower import parse_origin

    apply_spec(args, SPEC_FIELDS)
    home = parse_home(args.home) or HOME
    follow = _none(args.autopilot_pose)
    mav = _none(args.mavlink if args.mavlink is not None else (None if follow else DEFAULT_VEHICLE_URL))
    if follow and mav:
        raise UavRobotsError("with --autopilot-pose the world runs no vehicle: give --mavlink to the autopilot "
                             "(`uav-robots vehicle`)")
    if args.autopilot_origin is not None and not follow:
        raise UavRobotsError("--autopilot-origin places a followed autopilot: give --autopilot-pose URL too")
    camera_model_from(args.camera, DRONE_CAMERA)   # every value checked before anything starts
    preset = camera_preset(args.camera)
    wobble = WOBBLE_OF_CAMERA_PRESET[preset] if args.wobble is None else args.wobble
    faults = world_faults(args.fault)
    cfg = WorldConfig(fleet=args.fleet, map=args.map, robots=args.robots, seed=args.seed, scen=args.scen,
                      connectivity=args.connectivity, cell_size_m=args.cell_size, home_lat=home[0],
                      home_lon=home[1], home_alt_m=home[2], mavlink=mav, time_scale=args.time_scale,
                      camera={**DRONE_CAMERA, **camera_options(args.camera)}, scene=scene_of_args(args, preset),
                      wobble_deg=wobble, connect=args.connect, listen=args.listen,
                      zenoh_config=args.zenoh_config, move_batch_timeout_s=args.move_timeout,
                      slip=faults.slip, skids=faults.skids, gcs=args.gcs, mavlink_key=args.mavlink_key,
                      mavlink_bind=args.mavlink_bind, camera_mavlink=_none(args.camera_mavlink),
                      camera_video=_none(args.camera_video), autopilot_pose=follow,
                      autopilot_origin=parse_origin(args.autopilot_origin))
    if cfg.camera_video:
        from .camera.stream import require_pyav, video_config
        video_config(cfg.camera_video)
        require_pyav()
    cfg.check()
    return cfg


def world_command(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    world = World(cfg)
    world.camera_faults = world_faults(args.fault).camera   # camera-off / camera-stuck: sim_world/camera_faults.py
    world.stop_on_signals()
    try:
        try:
            world.start()
        except MissionError:
            if world.stop.is_set():   # stopped while it was still looking for a router: not an error
                return 0
            raise
        print(f"world ready: {world.describe()}", flush=True)
        reason = world.run()
    finally:
        world.close()
    print(f"world: {reason or 'stopped'}; {world.judge.tick} ticks, {world.judge.collisions} collisions",
          flush=True)
    return 0
