"""`uav-robots secure init DIR`: make a secure fleet's directory (`fleet.py` says what it holds)."""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from protocol.errors import UavRobotsError
from protocol.keys import DEFAULT_FLEET
from protocol.messages import MAX_ROBOTS

from ..common.robot_groups import robot_groups
from .fleet import DEFAULT_PORT, make_fleet_dir, new_fleet


def init_command(args: argparse.Namespace) -> int:
    out = Path(args.dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UavRobotsError(f"{args.dir}: exists and is not an empty directory (keys are never overwritten)")
    if args.robots_per_process is not None and args.robots_per_process < 1:
        raise UavRobotsError(f"--robots-per-process must be at least 1, got {args.robots_per_process}")
    groups = robot_groups(args.robots, args.robots_per_process) if 1 <= args.robots <= MAX_ROBOTS else []
    fleet = new_fleet(args.fleet, args.robots, groups, args.address, args.port,
                      Path(args.files_at) if args.files_at else out.resolve())
    make_fleet_dir(out, fleet)
    print(f"secure fleet {fleet.fleet} in {out}: CA, {len(fleet.identities())} certificates and configs "
          f"(uav router at {', '.join(fleet.addresses)} port {fleet.port})", flush=True)
    return 0


def add_secure_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("secure", help="certificates and Zenoh configs for mutual TLS and access control")
    sub = p.add_subparsers(dest="secure_command", required=True)
    i = sub.add_parser("init", help="make a CA, a certificate, a key and a Zenoh config per process")
    i.add_argument("dir", metavar="DIR", help="an empty or new directory")
    i.add_argument("--robots", type=int, required=True, help="number of robots (ids 0..N-1)")
    i.add_argument("--fleet", default=DEFAULT_FLEET, help=f"fleet name (default {DEFAULT_FLEET})")
    i.add_argument("--robots-per-process", type=int, default=None,
                   help="robots per robot process, as for `run` (default: 1 up to 64 robots, then 4 pools)")
    i.add_argument("--address", action="append", default=[], metavar="HOST",
                   help="an address the UAV's router is reached at (repeatable; the first is what clients "
                        "dial; default 127.0.0.1)")
    i.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"the router's TLS port (default {DEFAULT_PORT})")
    i.add_argument("--files-at", default=None, metavar="PATH",
                   help="where the files will be on the hosts that use them (default: DIR, absolute)")
    i.set_defaults(func=init_command)
    return p
