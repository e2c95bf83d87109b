"""Every benchmark is registered the same way: one table, one module each, each in the docs with its command."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

from uav_robots.bench.cli import BENCHMARKS, add_bench_parser, benchmark, run

REPO = Path(__file__).resolve().parents[2]


def test_every_benchmark_in_the_table_is_a_subcommand_run_by_its_module():
    top = argparse.ArgumentParser()
    add_bench_parser(top.add_subparsers(dest="command"))
    modules = {name: benchmark(name) for name in BENCHMARKS}
    assert len(set(modules.values())) == len(BENCHMARKS)
    for name, module in modules.items():
        assert callable(module.run), name
        args = top.parse_args(["bench", name])
        assert args.bench == name and args.func is run, name


def test_the_benchmarks_page_lists_every_benchmark_with_its_command():
    page = (REPO / "docs" / "benchmarks.md").read_text()
    section = page.split("## The benchmark commands", 1)[1].split("\n## ", 1)[0]
    listed = re.findall(r"^    uav-robots bench (\w+) +# \S", section, flags=re.MULTILINE)
    assert sorted(listed) == sorted(BENCHMARKS)
