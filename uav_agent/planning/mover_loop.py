"""A fleet run tick by tick among movers it sees only now and then: the tracker, the forecast
and the rolling-horizon repair in a closed loop, without a network.

Each tick k: an image every `look_every` ticks shows the movers where they are (`Floor.look`)
and is folded into the tracks (`forecast.py`) and the sets of cells where movers may be
(`mover_sets.py`); the forecast from those sets up to k + W closes cells; the
plan is repaired around them (`avoid.py`); the robots take one step of it and the movers one
of theirs, and the floor reports the tick's contacts (`Floor.step`). The floor is a
parameter, so that this module needs no world: the tests and the benchmark pass one that
steps `sim_world.movers` (the UAV's side may not import the world's).

The report is what the issue asks to see: contacts (the goal: none), ticks held, replans
and their time, and the makespan against the plan's own, the same instance without movers.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .avoid import BUDGET_S, Repair, repair, warm_up
from .forecast import Tracker
from .mover_sets import MoverSets
from .types import Cell, arrival


class Floor(Protocol):
    def look(self) -> list[tuple[str, Cell]]:
        """An image of the floor now: every mover in view as (kind, cell)."""

    def step(self, tick: int, before: Mapping[int, Cell], after: Mapping[int, Cell]) -> Sequence[Any]:
        """Tick `tick`: the robots go from `before` to `after` while the movers take their step;
        the contacts between them."""


@dataclass(frozen=True)
class LoopReport:
    look_every: int
    window: int
    ticks: int                        # ticks run
    makespan: int | None              # the tick the last robot was on its goal for good; None: not in time
    planned_makespan: int             # the plan's, as if the floor were empty
    sum_of_costs: int | None          # each robot's tick on its goal for good, summed; None: not all in time
    planned_sum_of_costs: int
    looks: int                        # images taken
    contacts: tuple[Any, ...]
    robot_conflicts: int              # ticks two robots met (a shared cell or a swap): the plans' own check
    held: int                         # robot-ticks held by a repair
    replans: int                      # ticks on which the repair changed a path
    replanned: int                    # robot paths changed by repairs, in all
    frozen: int                       # ticks on which every robot was held
    dropped: int                      # tracks the tracker gave up
    repair_ms: tuple[float, ...]      # each tick's repair
    forecast_ms: tuple[float, ...]    # each tick's forecast

    @property
    def ratio(self) -> float | None:
        """Makespan among movers over the empty floor's."""
        if self.makespan is None:
            return None
        return self.makespan / max(self.planned_makespan, 1)


def run_among_movers(free: np.ndarray, paths: Mapping[int, Sequence[Cell]], floor: Floor, *, look_every: int,
                     window: int | None = None, connectivity: int = 4, max_ticks: int | None = None,
                     budget_s: float = BUDGET_S,
                     on_tick: Callable[[int, Mapping[int, Sequence[Cell]], Repair], None] | None = None) -> LoopReport:
    """Runs the plan `paths` (robot -> cells per tick from tick 0, goal last) to the end on `floor`.

    window: the ticks ahead the forecast is applied (default: up to the next image and one more,
    so that the plan made on an image is safe until the next even if a tick's repair does not
    run; 1 is as safe here, where every tick is repaired, and holds robots back less).
    max_ticks: give up after so many (default: four times the plan's makespan, and 100 more).
    on_tick: called after each tick's repair with the tick, the plan from it on and the repair.
    """
    if look_every < 1:
        raise ValueError(f"an image every {look_every} ticks: at least every tick")
    window = look_every + 1 if window is None else window
    goals = {r: tuple(p[-1]) for r, p in paths.items()}
    arrivals = {r: arrival(list(p), goals[r]) for r, p in paths.items()}
    planned = max(arrivals.values(), default=0)
    last_move = {r: 0 for r in paths}
    looks = 0
    max_ticks = 4 * planned + 100 if max_ticks is None else max_ticks
    plan: dict[int, Sequence[Cell]] = {r: [tuple(c) for c in p] for r, p in paths.items()}
    warm_up()       # a first tick's repair must not pay for compiling the kernels
    tracker = Tracker(free)     # who is who, for the report; where nobody can be: the sets
    sets = MoverSets(free)
    contacts: list[Any] = []
    repair_ms: list[float] = []
    forecast_ms: list[float] = []
    held = replans = replanned = frozen = conflicts = 0
    makespan = None
    tick = 0
    while tick < max_ticks:
        if all(arrival(list(p), goals[r]) == 0 for r, p in plan.items()):
            makespan = tick
            break
        if tick % look_every == 0:
            shown = floor.look()
            tracker.update(tick, shown)
            sets.look(tick, shown)
            looks += 1
        t = time.perf_counter()
        sets.advance(tick)
        fc = sets.forecast(tick + window)
        forecast_ms.append(1e3 * (time.perf_counter() - t))
        rep = repair(free, plan, fc, tick, window, connectivity, budget_s=budget_s)
        repair_ms.append(1e3 * rep.seconds)
        held += len(rep.held)
        replanned += len(rep.replanned)
        replans += bool(rep.replanned or rep.held)
        frozen += rep.frozen
        plan = rep.paths
        if on_tick is not None:
            on_tick(tick, plan, rep)
        before = {r: p[0] for r, p in plan.items()}
        after = {r: p[1] if len(p) > 1 else p[0] for r, p in plan.items()}
        tick += 1
        contacts.extend(floor.step(tick, before, after))
        moves = {(before[r], after[r]) for r in plan if before[r] != after[r]}
        last_move.update((r, tick) for r in plan if before[r] != after[r])
        conflicts += len(set(after.values())) < len(after) or any((b, a) in moves for a, b in moves)
        plan = {r: p[1:] if len(p) > 1 else p for r, p in plan.items()}
    soc = sum(last_move.values()) if makespan is not None else None
    return LoopReport(look_every, window, tick, makespan, planned, soc, sum(arrivals.values()), looks, tuple(contacts), conflicts, held, replans,
                      replanned, frozen, len(tracker.dropped), tuple(repair_ms), tuple(forecast_ms))
