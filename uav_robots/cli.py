"""The `uav-robots` command: run a whole mission, or one part of it, plan and benchmark alone, check conformance."""
from __future__ import annotations

import argparse
import importlib
import sys

from protocol.process import command_main


def _add_run(sub) -> None:
    from sim_world.vehicle_cli import add_ground_station_arguments
    from uav_agent.cli import add_planning_arguments

    p = sub.add_parser("run", help="run a complete mission: world, UAV and robot processes")
    p.add_argument("--map", default="warehouse-small",
                   help="a .map file, warehouse-small, warehouse-450, 'warehouse:blocks_x=..,blocks_y=..' "
                        "or 'random:width=..,height=..,density=..' (default: warehouse-small)")
    p.add_argument("--robots", type=int, default=8, help="number of robots (default 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the placement (and random maps)")
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
    add_ground_station_arguments(p)
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
    p.add_argument("--camera-source", choices=("zenoh", "mavlink", "video"), default="zenoh",
                   help="how the UAV takes its images: zenoh (the world's world/camera query, default), mavlink "
                        "(the world's camera as a MAVLink camera: capture commands, images over HTTP) or video "
                        "(its H.264 RTP stream, the pose from telemetry)")
    p.add_argument("--robots-per-process", type=int, default=None,
                   help="robots hosted per process (default: 1 up to 64 robots, then 4 pools)")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help="inject a fault (repeatable): crash:ROBOT@TICK (the robot dies at that tick), "
                        "stall:ROBOT@TICK:TICKS (it stops moving and reporting that long), liar:ROBOT "
                        "(it raises Done at its start and stops); the world's: slip:P (any move ends "
                        "elsewhere with probability P), skid:ROBOT@TICK (from that tick every move of the "
                        "robot does: it keeps deviating)")
    p.add_argument("--monitor-every", type=int, default=None, metavar="K",
                   help="while the robots move, the UAV takes an image every K ticks and checks every robot "
                        "it sees against the plan (default: automatic, at most 20 %% of the execution time; 0: never)")
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
    p.set_defaults(func=lambda a: importlib.import_module("uav_robots.launcher").run(a))


def add_view_arguments(p) -> None:
    p.add_argument("--view", nargs="?", type=int, const=8765, default=None, metavar="PORT",
                   help="serve a live view of the mission at http://127.0.0.1:PORT/ (default port 8765; 0: any free)")
    p.add_argument("--view-hold", type=float, default=None, metavar="S",
                   help="keep the view up S seconds after the mission (default: until Ctrl-C on a terminal, "
                        "else 0)")


# Each subcommand is defined beside the code it runs and imported only when chosen:
# a robot process must not pay for scipy and OpenCV it never uses.
_SUBCOMMANDS = {
    "run": (__name__, "_add_run"),
    "uav": ("uav_agent.cli", "add_uav_parser"),
    "world": ("sim_world.cli", "add_world_parser"),
    "vehicle": ("sim_world.vehicle_cli", "add_vehicle_parser"),
    "robot": ("robot_agents.agent", "add_robot_parser"),
    "plan": ("uav_robots.plan_cli", "add_plan_parser"),
    "build": ("uav_robots.plan_cli", "add_build_parser"),
    "bench": ("uav_robots.plan_cli", "add_bench_parser"),
    "conformance": ("uav_robots.conformance_cli", "add_conformance_parser"),
    "replay": ("uav_robots.replay_cli", "add_replay_parser"),
    "secure": ("uav_robots.secure_cli", "add_secure_parser"),
}


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    chosen = argv[0] if argv and argv[0] in _SUBCOMMANDS else None
    parser = argparse.ArgumentParser(prog="uav-robots", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (module, adder) in _SUBCOMMANDS.items():
        if chosen in (None, name):
            getattr(importlib.import_module(module), adder)(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    return command_main(build_parser, argv)

if __name__ == "__main__":
    sys.exit(main())
