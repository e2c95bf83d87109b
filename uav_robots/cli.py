"""The `uav-robots` command: run a whole mission, or one part of it, plan and benchmark alone, check conformance."""
from __future__ import annotations

import argparse
import importlib
import sys

from protocol.process import command_main


# Each subcommand is defined beside the code it runs and imported only when chosen:
# a robot process must not pay for scipy and OpenCV it never uses.
_SUBCOMMANDS = {
    "run": ("uav_robots.run.arguments", "add_run_parser"),
    "uav": ("uav_agent.cli", "add_uav_parser"),
    "world": ("sim_world.cli", "add_world_parser"),
    "vehicle": ("sim_world.vehicle_cli", "add_vehicle_parser"),
    "robot": ("robot_agents.agent", "add_robot_parser"),
    "plan": ("uav_robots.plan_cli", "add_plan_parser"),
    "build": ("uav_robots.plan_cli", "add_build_parser"),
    "bench": ("uav_robots.bench.cli", "add_bench_parser"),
    "conformance": ("uav_robots.conformance_cli", "add_conformance_parser"),
    "replay": ("uav_robots.record.replay_cli", "add_replay_parser"),
    "secure": ("uav_robots.secure.cli", "add_secure_parser"),
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
