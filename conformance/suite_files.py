"""Where each side's suite is: the `test_robot_*.py` or `test_uav_*.py` files beside this one, one pytest run.

The suites are split by rule family into several files; whatever runs a whole suite (the
`uav-robots conformance` command, our tests) takes its files from here, so that a new file
of a family is run without anyone naming it.
"""
from __future__ import annotations

import importlib
from pathlib import Path
from typing import Callable

HERE = Path(__file__).resolve().parent
SUITES = {"robot": "test_robot_*.py", "uav": "test_uav_*.py"}


def suite_files(side: str) -> list[Path]:
    """The files of `side`'s suite, in the order pytest is given them (a UAV suite's slowest missions last)."""
    return sorted(HERE.glob(SUITES[side]))


def side_of(module: str) -> str | None:
    """The side whose suite the test module `module` (a dotted name) belongs to; None for no suite's."""
    name = module.rsplit(".", 1)[-1]
    return next((side for side in SUITES if name.startswith(f"test_{side}_")), None)


def suite_tests(side: str) -> dict[str, Callable]:
    """Every test function of `side`'s suite by name: the names the rule table gives pytest's -k are unique."""
    tests: dict[str, Callable] = {}
    for path in suite_files(side):
        module = importlib.import_module(f"{__package__}.{path.stem}")
        for name, value in vars(module).items():
            if name.startswith("test_") and callable(value):
                if name in tests and tests[name] is not value:
                    raise ValueError(f"test {name} is in two files of the {side} suite: -k cannot tell them apart")
                tests[name] = value
    return tests
