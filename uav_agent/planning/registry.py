"""Planner names -> planner functions, the one place the CLI and the pipeline look them up.

Each entry imports its module on first call: the numba planners compile (or load
their cache) at import time, which a `--planner paper-astar` run should not pay,
and a command that only lists planners should not pay at all.
"""
from __future__ import annotations

import importlib

from protocol.errors import PlanningError

from .types import Limits, Path, Planner, Problem

# name -> (module under uav_agent.planning, function name, complete?)
_SPECS: dict[str, tuple[str, str, bool]] = {
    "paper-astar": ("paper", "paper_astar", False),
    "paper-prm": ("paper", "paper_prm", False),
    "prioritized": ("prioritized", "prioritized", False),
    "pibt": ("pibt", "pibt", False),
    "lacam": ("lacam", "lacam", True),
}

# LaCAM is complete and, with PIBT as its configuration generator, the fastest of them.
DEFAULT_PLANNER = "lacam"

# The paper's pipelines (single-robot paths + priority waits) are incomplete by design.
PAPER_PLANNERS = frozenset({"paper-astar", "paper-prm"})


def _lazy(name: str) -> Planner:
    module, func, _ = _SPECS[name]

    def planner(problem: Problem, limits: Limits) -> list[Path]:
        impl = getattr(importlib.import_module(f"{__package__}.{module}"), func)
        return impl(problem, limits)

    planner.__name__ = func
    planner.__qualname__ = func
    planner.__doc__ = f"The {name!r} planner ({__package__}.{module}.{func}), imported on first call."
    return planner


PLANNERS: dict[str, Planner] = {name: _lazy(name) for name in _SPECS}


def is_complete(name: str) -> bool:
    """True if the planner finds a plan whenever one exists (given time)."""
    return _SPECS[check_name(name)][2]


def check_name(name: str) -> str:
    if name not in PLANNERS:
        raise PlanningError(f"unknown planner {name!r}: choose one of {', '.join(PLANNERS)}")
    return name


def get_planner(name: str) -> Planner:
    return PLANNERS[check_name(name)]
