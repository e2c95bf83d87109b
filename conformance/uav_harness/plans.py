"""Whether a robot must refuse a plan: judged against the floor's truth, independent of our planners."""
from __future__ import annotations

from typing import Any

from protocol.grid import Cell, on_grid
from protocol.messages import Plan


def step_ok(a: Cell, b: Cell, connectivity: int) -> bool:
    dx, dy = abs(b[0] - a[0]), abs(b[1] - a[1])
    return dx + dy <= 1 if connectivity == 4 else max(dx, dy) <= 1


def plan_problem(plan: Plan, rid: int, cell: Cell, truth: Any, connectivity: int) -> str:
    """Why a robot standing on `cell` must refuse `plan` ('' if it is executable): independent of our planners."""
    h, w = truth.free.shape
    if plan.robot != rid:
        return f"plan on robot {rid}'s key names robot {plan.robot}"
    if not plan.plan_id:
        return "empty plan_id"
    if not plan.path:
        return "empty path"
    if tuple(plan.path[0]) != tuple(cell):
        return f"path starts at {tuple(plan.path[0])}, the robot stands on {tuple(cell)}"
    for i, (x, y) in enumerate(plan.path):
        if not on_grid(x, y, w, h):
            return f"path cell {i} {(x, y)} is off the {w}x{h} grid"
        if not truth.free[y, x]:
            return f"path cell {i} {(x, y)} is an obstacle"
        if i and not step_ok(tuple(plan.path[i - 1]), (x, y), connectivity):
            return f"path step {i} {tuple(plan.path[i - 1])} -> {(x, y)} is not a {connectivity}-connected move"
    if tuple(plan.path[-1]) != tuple(plan.goal):
        return f"path ends at {tuple(plan.path[-1])}, not on its goal {tuple(plan.goal)}"
    if tuple(plan.goal) not in {tuple(g) for g in truth.goals}:
        return f"goal {tuple(plan.goal)} is not a goal marker on the floor"
    return ""
