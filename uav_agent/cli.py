"""The UAV agent's command line: `python -m uav_agent` or `uav-robots uav`."""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from protocol.config import add_session_arguments
from protocol.keys import DEFAULT_FLEET
from protocol.process import one_command
from protocol.run_spec import add_spec_argument, apply_spec

MAVSDK_DEFAULT = "udpin://0.0.0.0:14540"


def add_planning_arguments(p: argparse.ArgumentParser) -> None:
    """The planning options `uav`, `run` and `plan` share."""
    from .planning.assignment import ASSIGNERS, DEFAULT_ASSIGNMENT
    from .planning.registry import DEFAULT_PLANNER, PLANNERS

    # Not argparse choices: an unknown planner gets the same one-line error as any bad input.
    p.add_argument("--planner", default=None,
                   help=f"{', '.join(PLANNERS)} (default {DEFAULT_PLANNER}, the fastest complete one)")
    p.add_argument("--assign", default=None, choices=list(ASSIGNERS),
                   help="goal assignment: " + "; ".join(f"{k}: {a.help}" for k, a in ASSIGNERS.items())
                        + f" (default {DEFAULT_ASSIGNMENT})")
    p.add_argument("--connectivity", type=int, default=4, choices=[4, 8])
    p.add_argument("--time-limit", type=float, default=60.0, help="planning time limit in seconds")
    p.add_argument("--no-fallback", action="store_true",
                   help="stop when the paper's priority waits cannot resolve a conflict instead of "
                        "falling back to a complete planner")


def add_uav_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("uav", help="the UAV agent alone (leader: fly, see, plan, drive, land)")
    add_uav_arguments(p)
    p.set_defaults(func=uav_command)
    return p


def add_uav_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fleet", default=DEFAULT_FLEET, help=f"fleet name: keys live under uavr/<fleet> (default {DEFAULT_FLEET})")
    add_session_arguments(p, hub=True)
    p.add_argument("--mavlink", default=MAVSDK_DEFAULT, help=f"MAVSDK connection URL (default {MAVSDK_DEFAULT})")
    p.add_argument("--robots", type=int, default=None, help="expected fleet size (default: as many as seen)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="directory for report.json and images")
    p.add_argument("--tick-timeout", type=float, default=10.0,
                   help="seconds a robot may take to report a tick before it counts as stalled (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--observers", type=int, default=0, metavar="N",
                   help="before anything else, wait up to 5 s for N recorders' alive/observer tokens, so that "
                        "they record the mission from its start (default 0: wait for none)")
    p.add_argument("--summary", choices=("text", "json", "none"), default="text",
                   help="the end of mission summary: lines for a person, one JSON object (report.json's), or none")
    p.add_argument("--monitor-every", type=int, default=None, metavar="K",
                   help="while the robots move, one image every K ticks, checked against the plan "
                        "(default: automatic, at most 20 %% of the execution time; 0: never)")
    p.add_argument("--look-every", type=int, default=None, metavar="L",
                   help="people, forklifts and pallets on the floor: a look for them every L ticks, every robot's "
                        "step checked against where they may be (default: every 2 once the survey saw one; "
                        "0: never, the movers ignored)")
    p.add_argument("--tick-rate", type=float, default=0.0, metavar="HZ",
                   help="at most this many ticks per second, as robots that need time to cross a cell "
                        "(default 0: as fast as the fleet reports)")
    add_camera_source_arguments(p)
    add_planning_arguments(p)
    add_spec_argument(p)


# What the UAV takes from a run's spec (`--spec OUT/run.json`).
SPEC_FIELDS = {
    "--robots": lambda s: s.robots, "--seed": lambda s: s.seed, "--camera-source": lambda s: s.camera.source,
    "--planner": lambda s: s.planning.planner, "--assign": lambda s: s.planning.assign,
    "--connectivity": lambda s: s.planning.connectivity, "--time-limit": lambda s: s.planning.time_limit_s,
    "--no-fallback": lambda s: not s.planning.fallback, "--tick-timeout": lambda s: s.limits.tick_timeout_s,
    "--tick-rate": lambda s: s.limits.tick_rate_hz, "--monitor-every": lambda s: s.limits.monitor_every,
    "--look-every": lambda s: s.limits.look_every,
}


def add_camera_source_arguments(p: argparse.ArgumentParser) -> None:
    from .camera_source.base import DEFAULT_CAMERA_MAVLINK, KINDS

    p.add_argument("--camera-source", default="zenoh", metavar="|".join(KINDS),
                   help="where the images come from: zenoh (the world's world/camera query, default), mavlink (the "
                        "MAVLink camera protocol: a capture command, CAMERA_IMAGE_CAPTURED, the file over HTTP) or "
                        "video (an H.264 RTP stream, the pose from the autopilot's telemetry)")
    p.add_argument("--camera-mavlink", default=DEFAULT_CAMERA_MAVLINK, metavar="URL",
                   help=f"the camera component's MAVLink link (pymavlink URL; default {DEFAULT_CAMERA_MAVLINK})")
    p.add_argument("--camera-video", default=None, metavar="URL",
                   help="the video stream: udp://HOST:PORT (RTP H.264), an .sdp file or its URL (default: the "
                        "stream the camera component announces)")
    p.add_argument("--camera-calibration", default=None, metavar="FILE|URL",
                   help="the camera's calibration JSON (width, height, fx, fy, cx, cy, k1, k2, p1, p2, k3; default: "
                        "the calibration.json beside its definition file, else the pinhole it states)")


def camera_source_config(a: argparse.Namespace):
    """The --camera-* options, checked (one line for bad input)."""
    from .camera_source.base import CameraSourceConfig

    cfg = CameraSourceConfig(a.camera_source, a.camera_mavlink, a.camera_video, a.camera_calibration)
    cfg.check()
    return cfg


def uav_command(a: argparse.Namespace) -> int:
    from scenarios.limits import check_fleet

    from .mission import MissionConfig, run_mission
    from .report import exit_code, split_report, summary
    from .progress import Progress
    from .planning.assignment import DEFAULT_ASSIGNMENT

    spec = apply_spec(a, SPEC_FIELDS)
    if a.look_every is not None and a.look_every < 0:
        raise UavRobotsError(f"--look-every {a.look_every}: a number of ticks, 0 or more")
    if a.robots is not None:
        check_fleet(a.robots)
    cfg = MissionConfig(fleet=a.fleet, robots=a.robots, listen=a.listen, connect=a.connect,
                        zenoh_config=a.zenoh_config, mavlink_url=a.mavlink, planner=a.planner,
                        assign=a.assign or DEFAULT_ASSIGNMENT, connectivity=a.connectivity,
                        time_limit_s=a.time_limit, fallback=not a.no_fallback, seed=a.seed,
                        out=Path(a.out) if a.out else None, tick_timeout_s=a.tick_timeout,
                        tick_rate_hz=a.tick_rate,
                        monitor_every=a.monitor_every, look_every=a.look_every, observers=max(0, a.observers),
                        camera=camera_source_config(a), run=spec.as_dict() if spec is not None else None)
    report = run_mission(cfg, Progress(enabled=not a.quiet))
    if a.summary == "text":
        print(summary(report, cfg.out), flush=True)
    elif a.summary == "json":
        print(json.dumps(split_report(report)[0], separators=(",", ":")), flush=True)
    return exit_code(report)


build_parser = one_command("python -m uav_agent", "The UAV agent: fly, see, plan, drive, land.",
                           add_uav_arguments, uav_command)
