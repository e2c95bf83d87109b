"""The planners, one `PlannerSpec` row each: what the CLI, the pipeline, the warm-up and the build read.

A planner is named here once, beside its module: the pipeline looks its function up, refines
its plans or not; the warm-up process compiles its kernels and asks numba's cache for them;
the ahead-of-time build records its kernel calls (every planner, through the pipeline) and
puts its kernel modules in one of its two libraries.

Each planner's module is imported on its first call: the numba planners compile (or load
their cache) at import time, which a `--planner paper-astar` run should not pay, and a
command that only lists planners should not pay at all.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

from protocol.errors import PlanningError

from .types import Limits, Path, Planner, Problem


@dataclass(frozen=True)
class PlannerSpec:
    name: str                     # what --planner takes
    module: str                   # under uav_agent.planning, e.g. "mapf.pibt"
    function: str                 # (problem, limits) -> paths
    complete: bool = False        # finds a plan whenever one exists (given time): nothing to fall back to
    refinable: bool = False       # the pipeline's refinement may shorten its plans
    # numba kernels the warm-up compiles before a mission, one per family ("module.kernel"):
    # their cache indexes say whether the cache is warm. () for a planner compiled on first use
    kernels: tuple[str, ...] = ()
    aot_library: int = 0          # which of the build's two libraries (compiled side by side) takes `kernels`' modules
    warm_up: str = ""             # a function of `module` that compiles its kernels (parts=...): the warm-up runs it

    def load(self) -> Callable[[Problem, Limits], list[Path]]:
        return getattr(importlib.import_module(f"{__package__}.{self.module}"), self.function)


SPECS: tuple[PlannerSpec, ...] = (
    PlannerSpec("paper-astar", "paper.pipelines", "paper_astar"),
    PlannerSpec("paper-prm", "paper.pipelines", "paper_prm"),
    PlannerSpec("prioritized", "mapf.prioritized", "prioritized", refinable=True,
                kernels=("mapf.prioritized._plan_in_order",)),
    PlannerSpec("pibt", "mapf.pibt", "pibt", refinable=True, kernels=("mapf.pibt._run",), aot_library=1),
    PlannerSpec("lacam", "portfolio", "lacam", complete=True, refinable=True,
                kernels=("mapf.lacam._search", "mapf.scatter._scatter"), aot_library=1, warm_up="warm_up"),
)

# Kernels every planner runs through the pipeline, with the library the build puts them in:
# the distance fields (before any planner), and the refinement (after a refinable one)
DISTANCE_KERNELS = ("mapf.distances._bfs_rows",)
REFINE_KERNELS = ("mapf.refine._refine",)
REFINE_LIBRARY = 1

# LaCAM is complete and, with PIBT as its configuration generator, the fastest of them.
DEFAULT_PLANNER = "lacam"

# The paper's pipelines (single-robot paths + priority waits) are incomplete by design.
PAPER_PLANNERS = frozenset({"paper-astar", "paper-prm"})

BY_NAME: dict[str, PlannerSpec] = {s.name: s for s in SPECS}


def _lazy(spec: PlannerSpec) -> Planner:
    def planner(problem: Problem, limits: Limits) -> list[Path]:
        return spec.load()(problem, limits)

    planner.__name__ = spec.function
    planner.__qualname__ = spec.function
    planner.__doc__ = (f"The {spec.name!r} planner ({__package__}.{spec.module}.{spec.function}), "
                       "imported on first call.")
    return planner


PLANNERS: dict[str, Planner] = {s.name: _lazy(s) for s in SPECS}


def spec(name: str) -> PlannerSpec:
    return BY_NAME[check_name(name)]


def is_complete(name: str) -> bool:
    """True if the planner finds a plan whenever one exists (given time)."""
    return spec(name).complete


def check_name(name: str) -> str:
    if name not in PLANNERS:
        raise PlanningError(f"unknown planner {name!r}: choose one of {', '.join(PLANNERS)}")
    return name


def get_planner(name: str) -> Planner:
    return PLANNERS[check_name(name)]
