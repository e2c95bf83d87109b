"""Mutants: our own robot or UAV with exactly one protocol rule broken, to prove the suites catch it.

    python -m conformance.mutants robot --break R9 --id {id} --fleet {fleet} --connect {endpoint}
    python -m conformance.mutants uav --break U8 --fleet {fleet} --connect {endpoint} --mavlink {mavlink} ...

Everything after `--break ID` is the implementation's own command line
(`python -m robot_agents ...` or `python -m uav_agent ...`). Each break is a
small patch of `robot_agents` or `uav_agent` applied before its main runs; the
rule ids and the tests that must fail are in `conformance/rules.py`.
`--break none` runs the implementation unchanged (the control).
"""
from __future__ import annotations

import argparse
import sys

from . import robot_lifecycle, robot_messages, robot_plans, robot_ticks, uav
from .patching import Patch


def _robot_patches() -> dict[str, Patch]:
    # Every family is built before any patch is applied: each takes the real methods it builds on.
    table: dict[str, Patch] = {}
    for family in (robot_lifecycle, robot_plans, robot_ticks, robot_messages):
        table.update(family.patches())
    return dict(sorted(table.items(), key=lambda item: int(item[0][1:])))


def _robot_main(argv: list[str]) -> int:
    from protocol.process import command_main, one_command
    from robot_agents.agent import add_robot_arguments, robot_command

    return command_main(one_command("python -m conformance.mutants robot", "A robot with one rule broken.",
                                    add_robot_arguments, robot_command), argv)


def _uav_main(argv: list[str]) -> int:
    from protocol.process import command_main
    from uav_agent.cli import build_parser

    return command_main(build_parser, argv)


SIDES = {"robot": (_robot_patches, _robot_main), "uav": (uav.patches, _uav_main)}


def breaks(side: str) -> list[str]:
    """The rule ids that `side` has a mutant for."""
    return list(SIDES[side][0]())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m conformance.mutants", description=__doc__.splitlines()[0],
                                epilog="Anything after --break ID is the implementation's own command line.")
    p.add_argument("side", choices=list(SIDES))
    p.add_argument("--break", dest="rule", required=True, metavar="ID", help="the rule to break (R1.., U1..), or none")
    args, rest = p.parse_known_args(sys.argv[1:] if argv is None else argv)
    patches, run = SIDES[args.side]
    table = patches()
    if args.rule != "none":
        if args.rule not in table:
            p.error(f"no {args.side} mutant {args.rule!r}: choose one of {', '.join(table)} or none")
        table[args.rule]()
    return run(rest)
