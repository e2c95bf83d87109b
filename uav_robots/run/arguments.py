"""`uav-robots run`'s arguments: the parser, and every input checked before any process starts."""
from __future__ import annotations

import importlib
import math
import os
from pathlib import Path

from protocol.errors import MissionError, UavRobotsError
from protocol.faults import help_line as fault_help
from protocol.run_spec import add_spec_argument
from scenarios.scene import add_mover_arguments

from ..common.robot_groups import robot_groups
from ..view.arguments import add_view_arguments


def add_run_parser(sub) -> None:
    from scenarios.maps import MAP_HELP
    from sim_world.vehicle_cli import add_ground_station_arguments
    from uav_agent.cli import add_planning_arguments

    p = sub.add_parser("run", help="run a complete mission: world, UAV and robot processes")
    p.add_argument("--map", default="warehouse-small", help=f"{MAP_HELP} (default: warehouse-small)")
    p.add_argument("--robots", type=int, default=8, help="number of robots (default 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the placement (and random maps)")
    p.add_argument("--scen", default=None, metavar="FILE",
                   help="take the robots' starts and goals from a MovingAI .scen for the map (its first --robots "
                        "lines) instead of placing them by the seed")
    p.add_argument("--out", help="directory for report.json, overhead.png, paths.png, replay.gif, mission.mcap, "
                                 "replay.mp4, report.html, logs/ (an earlier run's there are removed first)")
    add_planning_arguments(p)
    p.add_argument("--time-scale", type=float, default=None,
                   help="simulated seconds per wall second for the vehicle (default 10; 1 with --autopilot, whose "
                        "clock runs at its own pace: give its speed-up)")
    p.add_argument("--camera", default="", metavar="[PRESET,]K=V,...",
                   help="the world's camera: a preset (ideal, realistic) then keys over it, e.g. 'ideal', "
                        "'realistic,blur_sigma=2' or 'ideal,width=1280,height=960,noise_std=6' (default: the "
                        "realistic 4000x3000, 90 deg camera; every key in docs/camera-and-perception.md)")
    p.add_argument("--scene", default="", metavar="[PRESET,]K=V,...",
                   help="what the world lays on the floor for the camera: a preset (ideal: goal discs, no "
                        "landmarks; realistic: goal pads, a surveyed landmark every 12 cells) then keys over it, "
                        "e.g. 'landmark_spacing=8' (default: the camera preset's namesake)")
    add_ground_station_arguments(p)
    add_mover_arguments(p)
    p.add_argument("--autopilot", default=None, metavar="URL",
                   help="fly whatever autopilot answers on this MAVLink link (the UAV's: PX4 SITL's API port, "
                        "e.g. udpin://0.0.0.0:14540) instead of starting our vehicle process; needs --autopilot-pose")
    p.add_argument("--autopilot-pose", default=None, metavar="URL",
                   help="with --autopilot: the link on which the world reads that autopilot's pose for its camera "
                        "(a ground station's port, e.g. udpin:127.0.0.1:14550)")
    p.add_argument("--autopilot-origin", default=None, metavar="home|N,E,D",
                   help="where the autopilot's local frame lies on the floor: 'home' (default: its first home "
                        "is the floor's top-left corner) or its local origin's N,E,D in metres (indoor, no GPS)")
    p.add_argument("--vehicle-preset", choices=("outdoor", "indoor"), default="outdoor",
                   help="our vehicle as an outdoor PX4 (GPS, a home; default) or an indoor one (no GPS: the UAV "
                        "flies its local frame in offboard, the world places it by its local origin)")
    p.add_argument("--wobble", type=float, default=None, metavar="DEG",
                   help="our vehicle's roll and pitch wobble in a hover, degrees (default: 0.3 with the realistic "
                        "camera, 0 with the ideal one)")
    p.add_argument("--camera-source", choices=("zenoh", "mavlink", "video"), default="zenoh",
                   help="how the UAV takes its images: zenoh (the world's world/camera query, default), mavlink "
                        "(the world's camera as a MAVLink camera: capture commands, images over HTTP) or video "
                        "(its H.264 RTP stream, the pose from telemetry)")
    p.add_argument("--robots-per-process", type=int, default=None,
                   help="robots hosted per process (default: 1 up to 64 robots, then 4 pools)")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC", help=fault_help())
    p.add_argument("--monitor-every", type=int, default=None, metavar="K",
                   help="while the robots move, the UAV takes an image every K ticks and checks every robot "
                        "it sees against the plan (default: automatic, at most 20 %% of the execution time; 0: never)")
    p.add_argument("--look-every", type=int, default=None, metavar="L",
                   help="with movers on the floor: the UAV looks for them every L ticks and checks every step "
                        "against where they may be (default: every 2 once its survey saw one; 0: never)")
    p.add_argument("--tick-timeout", type=float, default=10.0, metavar="S",
                   help="seconds a robot may take to report a tick before it counts as stalled (default 10)")
    p.add_argument("--tick-rate", type=float, default=0.0, metavar="HZ",
                   help="at most this many ticks per second (default 0: as fast as the fleet reports)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--quiet", action="store_true", help="no progress lines: only the summary (and errors)")
    out.add_argument("--json", action="store_true",
                     help="print only the summary, as one JSON object (report.json's, with the run's wall time)")
    p.add_argument("--timeout", type=float, default=900.0, help="give up after this many seconds")
    add_view_arguments(p)
    p.add_argument("--secure", nargs="?", const="", default=None, metavar="DIR",
                   help="mutual TLS and access control: a fresh CA and certificates in a temporary directory "
                        "(kept in OUT/secure with --out), or those of DIR from `uav-robots secure init`")
    # The mission's code (and what it imports) loads only when `run` is what runs.
    add_spec_argument(p)
    p.set_defaults(func=lambda a: importlib.import_module("uav_robots.run.mission").run(a))


def _number(name: str, value: float, lo: float, hi: float, lo_open: bool = False) -> None:
    ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        raise UavRobotsError(f"{name} must be a number in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {value:g}")


def check_autopilot(args) -> None:
    """--autopilot and --autopilot-pose go together, and leave our vehicle's options out; the time scale
    defaults to our vehicle's 10, or 1 for another autopilot (its clock runs at its own pace)."""
    from sim_world.pose_follower import check_pose_url, parse_origin

    given, pose = getattr(args, "autopilot", None), getattr(args, "autopilot_pose", None)
    if getattr(args, "time_scale", None) is None:
        args.time_scale = 1.0 if given else 10.0
    if bool(given) != bool(pose):
        raise UavRobotsError("--autopilot URL (the UAV's link) and --autopilot-pose URL (the world's) go together")
    if getattr(args, "autopilot_origin", None) is not None and not pose:
        raise UavRobotsError("--autopilot-origin places a followed autopilot: give --autopilot-pose URL too")
    if not given:
        return
    if args.gcs or args.mavlink_key or getattr(args, "vehicle_preset", "outdoor") != "outdoor":
        raise UavRobotsError("--gcs, --mavlink-key and --vehicle-preset configure our vehicle, which --autopilot "
                             "replaces: give a ground station its link on the autopilot itself")
    check_pose_url(pose, args.mavlink_bind)
    parse_origin(args.autopilot_origin)


def check_arguments(args) -> tuple[str, object]:
    """Every input of `run`, checked before any process starts: one line and exit 2 for the first bad one."""
    from protocol.bounds import MAX_ROBOTS
    from protocol.faults import parse_fault
    from scenarios.floor import setup_floor
    from scenarios.limits import check_fleet
    from sim_world.camera import CameraModel
    from scenarios.scene import scene_of_args
    from sim_world.traffic import build_traffic
    from sim_world.camera.model import camera_options, camera_preset
    from sim_world.config import DRONE_CAMERA, MOVE_BATCH_TIMEOUT_S, WorldConfig, vehicle_config

    _number("--robots", args.robots, 1, MAX_ROBOTS)
    check_fleet(args.robots)
    if getattr(args, "view", None) is not None:
        _number("--view", args.view, 0, 65535)
    if getattr(args, "view_hold", None) is not None:
        _number("--view-hold", args.view_hold, 0, 7 * 86400)
    _number("--seed", args.seed, 0, 2**32 - 1)
    check_autopilot(args)
    _number("--time-scale", args.time_scale, 0, 1000, lo_open=True)
    _number("--tick-rate", args.tick_rate, 0, 1000)
    _number("--timeout", args.timeout, 0, 7 * 86400, lo_open=True)
    _number("--time-limit", args.time_limit, 0, 86400, lo_open=True)
    if args.robots_per_process is not None:
        _number("--robots-per-process", args.robots_per_process, 1, MAX_ROBOTS)
    if args.monitor_every is not None:
        _number("--monitor-every", args.monitor_every, 0, 10**6)
    if args.look_every is not None:
        _number("--look-every", args.look_every, 0, 10**6)
    # Everyone waits for the world's batch when one robot is silent: a shorter deadline would call the
    # whole fleet stalled.
    _number("--tick-timeout", args.tick_timeout, MOVE_BATCH_TIMEOUT_S, 3600, lo_open=True)
    if args.out:
        out = Path(args.out)
        try:
            if out.exists() and not out.is_dir():
                raise UavRobotsError(f"--out {args.out}: is a file, not a directory")
            parent = next((p for p in [out, *out.resolve().parents] if p.exists()), None)
        except (OSError, ValueError) as exc:   # a name too long, a NUL byte
            raise UavRobotsError(f"--out {args.out[:80]!r}: not a directory name this system takes "
                                 f"({getattr(exc, 'strerror', None) or exc})") from None
        if parent is not None and not parent.is_dir():   # --out FILE/sub
            raise UavRobotsError(f"--out {args.out}: {parent} is a file, not a directory")
        if parent is None or not os.access(parent, os.W_OK):
            raise UavRobotsError(f"--out {args.out}: cannot write there")
    try:
        CameraModel(**{**DRONE_CAMERA, **camera_options(args.camera)})
    except (MissionError, TypeError) as exc:
        raise UavRobotsError(f"--camera {args.camera!r}: {exc}") from None
    scene = scene_of_args(args, camera_preset(args.camera))
    if args.wobble is not None:
        _number("--wobble", args.wobble, 0, 30)
    if not args.autopilot:
        vehicle_config(WorldConfig(fleet="check", gcs=args.gcs, mavlink_key=args.mavlink_key,
                                   mavlink_bind=args.mavlink_bind))
    for f in map(parse_fault, args.fault):
        if f.robot is not None and f.robot >= args.robots:
            raise UavRobotsError(f"--fault {f}: there is no robot {f.robot} in a fleet of {args.robots}")
    if args.planner:
        from uav_agent.planning.registry import get_planner

        get_planner(args.planner)
    if args.assign:   # a spec's (a command line's is one of argparse's choices)
        from uav_agent.planning.assignment import ASSIGNERS

        if args.assign not in ASSIGNERS:
            raise UavRobotsError(f"--assign {args.assign!r}: one of {', '.join(ASSIGNERS)}")
    if args.secure:
        from ..secure.fleet import read_fleet_dir

        made = read_fleet_dir(Path(args.secure))
        if made.robots != args.robots:
            raise UavRobotsError(f"--secure {args.secure} was made for {made.robots} robots: give --robots {made.robots}")
    elif args.secure is not None:
        from ..secure.fleet import MAX_ROBOT_PROCESSES

        if len(robot_groups(args.robots, args.robots_per_process)) > MAX_ROBOT_PROCESSES:
            raise UavRobotsError(f"--secure: at most {MAX_ROBOT_PROCESSES} robot processes (identities); "
                                 f"host more robots per process (--robots-per-process)")
    floor = setup_floor(args.map, args.seed, args.robots, args.scen)
    build_traffic(scene, floor.free, floor.starts, floor.goals, args.seed)
    return floor.name, floor.free
