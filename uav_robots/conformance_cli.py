"""`uav-robots conformance robot|uav --cmd "..."`: the conformance suites on any implementation, via pytest."""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile

from protocol.errors import UavRobotsError

SUITES = {"robot": "--robot-cmd", "uav": "--uav-cmd"}   # the option that gives each side's suite its --cmd


def add_conformance_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "conformance", help="check a robot or UAV implementation against the protocol",
        description="Run the conformance suite on an implementation started from a command line. Placeholders: "
                    "robot {id} {fleet} {endpoint}; uav {fleet} {endpoint} {mavlink} {mavlink_port} {robots} "
                    "{tick_timeout}. Without --cmd the project's own implementation is checked.")
    p.add_argument("kind", nargs="?", choices=list(SUITES), help="which side of the protocol the implementation plays")
    p.add_argument("--cmd", default=None, help="the implementation's command line, with placeholders")
    p.add_argument("--list-rules", action="store_true",
                   help="print the protocol rules the suite checks (of KIND, or all), with their tests, and exit")
    p.add_argument("pytest_args", nargs=argparse.REMAINDER,
                   help="anything after the options goes to pytest (e.g. -k liveliness, -x, --robot-timeout 5)")
    p.set_defaults(func=conformance_command)
    return p


def conformance_command(args: argparse.Namespace) -> int:
    from conformance.rules import text_table
    from conformance.suite_files import suite_files

    # Options after KIND land in pytest_args (argparse.REMAINDER takes all that follows a positional):
    # take ours back from there.
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--cmd", default=None)
    pre.add_argument("--list-rules", action="store_true")
    late, rest = pre.parse_known_args(args.pytest_args)
    cmd, list_rules = late.cmd or args.cmd, late.list_rules or args.list_rules
    if list_rules:
        print(text_table(args.kind))
        return 0
    if args.kind is None:
        raise UavRobotsError("conformance: give robot or uav (or --list-rules)")

    option, files = SUITES[args.kind], [str(path) for path in suite_files(args.kind)]
    with tempfile.TemporaryDirectory(prefix="uav-robots-conformance-") as base:
        # A temporary directory of its own: a numbered one would delete those of other pytest runs.
        argv = [sys.executable, "-m", "pytest", *files, "-q", "-p", "no:cacheprovider", f"--basetemp={base}",
                *([option, cmd] if cmd else []), *rest]
        # pytest's own exit code: 0 all rules kept, 1 a rule broken, 2-4 usage problems.
        return subprocess.run(argv, stdin=subprocess.DEVNULL).returncode
