"""The `uav-robots` command: run a whole mission, or one part of it, or plan and benchmark alone."""
from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path

from protocol.errors import MissionError, UavRobotsError

MAVSDK_DEFAULT = "udpin://0.0.0.0:14540"


def _add_run(sub) -> None:
    p = sub.add_parser("run", help="run a complete mission: world, UAV and robot processes")
    p.add_argument("--map", default="warehouse-small",
                   help="a .map file, warehouse-small, warehouse-450, 'warehouse:blocks_x=..,blocks_y=..' "
                        "or 'random:width=..,height=..,density=..' (default: warehouse-small)")
    p.add_argument("--robots", type=int, default=8, help="number of robots (default 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the placement (and random maps)")
    p.add_argument("--out", help="directory for report.json, overhead.png, paths.png, replay.gif, logs/")
    _add_planning_options(p)
    p.add_argument("--time-scale", type=float, default=10.0,
                   help="simulated seconds per wall second for the vehicle (default 10)")
    p.add_argument("--camera", default="",
                   help="camera options for the world, e.g. 'width=1280,height=960,hfov_deg=84,noise_std=6,"
                        "blur_sigma=1,lighting=0.3' (default 4000x3000, 90 deg, clean)")
    p.add_argument("--robots-per-process", type=int, default=None,
                   help="robots hosted per process (default: 1 up to 64 robots, then 4 pools)")
    p.add_argument("--timeout", type=float, default=900.0, help="give up after this many seconds")
    p.set_defaults(func=lambda a: __import__("uav_agent.launcher", fromlist=["run"]).run(a))


def _add_planning_options(p) -> None:
    p.add_argument("--planner", default=None,
                   help="paper-astar, paper-prm, prioritized, pibt or lacam (default: the fastest complete one)")
    p.add_argument("--assign", default="optimal", choices=["optimal", "bottleneck", "bruteforce", "none"])
    p.add_argument("--connectivity", type=int, default=4, choices=[4, 8])
    p.add_argument("--time-limit", type=float, default=60.0, help="planning time limit in seconds")
    p.add_argument("--no-fallback", action="store_true",
                   help="stop when the paper's priority waits cannot resolve a conflict instead of "
                        "falling back to a complete planner")


def _add_uav(sub) -> None:
    p = sub.add_parser("uav", help="the UAV agent alone (leader: fly, see, plan, drive, land)")
    p.add_argument("--fleet", required=True, help="fleet name: keys live under uavr/<fleet>")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--listen", action="append", help="be the Zenoh hub, listening here (default tcp/127.0.0.1:7447)")
    g.add_argument("--connect", action="append", help="join a Zenoh router at this endpoint")
    g.add_argument("--zenoh-config", help="a JSON5 Zenoh config file (TLS, remote router, ...)")
    p.add_argument("--mavlink", default=MAVSDK_DEFAULT, help=f"MAVSDK connection URL (default {MAVSDK_DEFAULT})")
    p.add_argument("--robots", type=int, default=None, help="expected fleet size (default: as many as seen)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="directory for report.json and images")
    p.add_argument("--tick-timeout", type=float, default=10.0)
    _add_planning_options(p)
    p.set_defaults(func=_run_uav)


def _run_uav(a) -> int:
    from .mission import Mission, MissionConfig

    cfg = MissionConfig(fleet=a.fleet, robots=a.robots, listen=a.listen or [], connect=a.connect or [],
                        zenoh_config=a.zenoh_config, mavlink_url=a.mavlink, planner=a.planner, assign=a.assign,
                        connectivity=a.connectivity, time_limit_s=a.time_limit, fallback=not a.no_fallback,
                        seed=a.seed, out=Path(a.out) if a.out else None, tick_timeout_s=a.tick_timeout)
    report = Mission(cfg).run()
    from .mission import summary

    print(summary(report, cfg.out), flush=True)
    return 0 if report["completed"] else 1


# Subcommands defined beside the code they run, imported only when chosen: a robot
# process should not pay for scipy and OpenCV it never uses.
_ELSEWHERE = {
    "world": ("sim_world.world", "add_world_parser"),
    "robot": ("robot_agents.agent", "add_robot_parser"),
    "plan": ("uav_agent.plan_cli", "add_plan_parser"),
    "bench": ("uav_agent.plan_cli", "add_bench_parser"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    import importlib

    parser = argparse.ArgumentParser(prog="uav-robots", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    _add_run(sub)
    _add_uav(sub)
    for name, (module, adder) in _ELSEWHERE.items():
        if command in (None, name):
            getattr(importlib.import_module(module), adder)(sub)
    return parser


def _on_sigterm(signum, frame) -> None:
    # Unwind like Ctrl-C, so every `finally` closes its Zenoh session (a live one never exits).
    raise SystemExit(143)


def main(argv: list[str] | None = None) -> int:
    signal.signal(signal.SIGTERM, _on_sigterm)
    argv = sys.argv[1:] if argv is None else list(argv)
    command = argv[0] if argv and argv[0] in _ELSEWHERE else None
    args = build_parser(command).parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except MissionError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 1
    except UavRobotsError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr, flush=True)
        return 130


if __name__ == "__main__":
    sys.exit(main())
