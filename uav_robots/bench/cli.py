"""`uav-robots bench NAME`: the table of benchmarks. Each is a module of this package with the same
entry: `add_parser(sub)` adds its subcommand and returns its parser, `run(args)` runs it and returns
the exit code."""
from __future__ import annotations

import argparse
import importlib
from types import ModuleType

from protocol.errors import UavRobotsError

from ..common.arguments import fail

# NAME -> its module in this package, in the order `uav-robots bench --help` lists them.
BENCHMARKS = {
    "paper": "paper",
    "movingai": "movingai",
    "command": "command",
    "secure": "secure",
    "perception": "perception",
    "ticks": "ticks",
    "mission": "mission",
    "faults": "faults",
    "camera": "camera",
    "movers": "movers",
}


def benchmark(name: str) -> ModuleType:
    return importlib.import_module(f"{__package__}.{BENCHMARKS[name]}")


def add_bench_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("bench", help="benchmarks: the paper's Table 2 and MovingAI instances",
                              description="Run the planning benchmarks; writes a markdown table and CSV files.")
    sub = p.add_subparsers(dest="bench", metavar="{" + ",".join(BENCHMARKS) + "}", required=True)
    for name in BENCHMARKS:
        benchmark(name).add_parser(sub).set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    try:
        return benchmark(args.bench).run(args)
    except UavRobotsError as exc:
        return fail(exc)
    except KeyboardInterrupt:
        return fail(UavRobotsError("interrupted"))
