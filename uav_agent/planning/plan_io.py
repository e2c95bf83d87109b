"""Plan files, format `uav-robots-plan/1`: plain JSON a user can load without our code.

    {"format": "uav-robots-plan/1",
     "map": {"name", "width", "height", "rows": [MovingAI rows, '.' free, '@' blocked]},
     "connectivity": 4, "planner": name, "requested_planner": name, "assign": mode,
     "fell_back": bool, "notes": [...],
     "robots": [{"id", "start": [x, y], "goal": [x, y], "cost": step, "path": [[x, y], ...]}],
     "metrics": {"sum_of_costs", "makespan", "lower_bound", ...},
     "timings": {"total": s, "<phase>": s}}

x is the column, y the row (top-left origin); path[t] is the cell at step t, path[0]
the start, the last cell the goal, where the robot then stays. A robot's cost is the
step at which it last arrives at its goal.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path as FsPath
from typing import TYPE_CHECKING, Any

import numpy as np

from protocol.errors import MapError, PlanningError
from protocol.grid import on_grid
from protocol.mapfile import format_rows, parse_rows

from .types import Cell, Path, Problem, sum_of_costs
from .validator import check

if TYPE_CHECKING:  # the pipeline pulls in the numba planners; a plan reader needs none of them
    from .pipeline import PlanResult

FORMAT = "uav-robots-plan/1"


@dataclass
class LoadedPlan:
    free: np.ndarray
    ids: list[int]
    starts: list[Cell]
    goals: list[Cell]
    paths: list[Path]
    connectivity: int
    planner: str = ""
    map_name: str = ""
    metrics: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def problem(self) -> Problem:
        return Problem(free=self.free, starts=self.starts, goals=self.goals, connectivity=self.connectivity)


def plan_to_dict(result: PlanResult, free: np.ndarray, ids: list[int] | None = None,
                 map_name: str = "") -> dict[str, Any]:
    n = len(result.paths)
    ids = list(range(n)) if ids is None else [int(i) for i in ids]
    if len(ids) != n:
        raise PlanningError(f"{len(ids)} robot ids for {n} paths")
    if len(set(ids)) != n:
        raise PlanningError("robot ids must be distinct")
    h, w = free.shape
    robots = []
    for rid, s, g, p in zip(ids, result.starts, result.goals, result.paths):
        robots.append({"id": rid, "start": [s[0], s[1]], "goal": [g[0], g[1]],
                       "cost": sum_of_costs([p], [g]), "path": [[x, y] for x, y in p]})
    return {
        "format": FORMAT,
        "map": {"name": map_name, "width": w, "height": h, "rows": format_rows(free)},
        "connectivity": result.connectivity,
        "planner": result.planner,
        "requested_planner": result.requested,
        "assign": result.assign,
        "fell_back": result.fell_back,
        "notes": list(result.notes),
        "metrics": dict(result.metrics),
        "timings": {k: round(v, 6) for k, v in result.timings.items()},
        "robots": robots,
    }


def dumps(plan: dict[str, Any]) -> str:
    """Valid JSON laid out for people: one map row and one robot per line."""
    parts = []
    for key, value in plan.items():
        if key == "robots":
            body = ",\n  ".join(json.dumps(r, separators=(",", ":")) for r in value)
            parts.append(f' "robots": [\n  {body}\n ]' if value else ' "robots": []')
        elif key == "map":
            head = {k: v for k, v in value.items() if k != "rows"}
            rows = ",\n   ".join(json.dumps(r) for r in value.get("rows", []))
            inner = json.dumps(head)[1:-1]
            parts.append(f' "map": {{{inner}, "rows": [\n   {rows}\n  ]}}')
        else:
            parts.append(f" {json.dumps(key)}: {json.dumps(value)}")
    return "{\n" + ",\n".join(parts) + "\n}\n"


def write_plan(path: str | FsPath, result: PlanResult, free: np.ndarray, ids: list[int] | None = None,
               map_name: str = "") -> dict[str, Any]:
    plan = plan_to_dict(result, free, ids, map_name)
    path = FsPath(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(dumps(plan), encoding="utf-8")
    except OSError as exc:
        raise PlanningError(f"cannot write plan file {path}: {exc.strerror or exc}") from None
    return plan


def _cell(value: Any, where: str, w: int, h: int) -> Cell:
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
        raise PlanningError(f"{where} is {json.dumps(value)[:40]}, not [x, y] integers")
    x, y = value
    if not on_grid(x, y, w, h):
        raise PlanningError(f"{where} ({x}, {y}) is off the {w}x{h} map")
    return (x, y)


def plan_from_dict(d: Any, name: str = "plan") -> LoadedPlan:
    if not isinstance(d, dict):
        raise PlanningError(f"{name}: not a JSON object")
    if d.get("format") != FORMAT:
        raise PlanningError(f"{name}: format is {d.get('format')!r}, expected {FORMAT!r}")
    m = d.get("map")
    if not isinstance(m, dict) or not isinstance(m.get("rows"), list) \
            or not all(isinstance(r, str) for r in m["rows"]):
        raise PlanningError(f"{name}: 'map' must hold 'rows', a list of strings")
    try:
        free = parse_rows(m["rows"], name)
    except MapError as exc:  # a plan file's reader promises PlanningError, whatever part is wrong
        raise PlanningError(str(exc)) from None
    h, w = free.shape
    if (m.get("width", w), m.get("height", h)) != (w, h):
        raise PlanningError(f"{name}: map says {m.get('width')}x{m.get('height')}, rows are {w}x{h}")
    conn = d.get("connectivity", 4)
    if type(conn) is not int or conn not in (4, 8):
        raise PlanningError(f"{name}: connectivity must be 4 or 8, got {conn!r}")
    robots = d.get("robots")
    if not isinstance(robots, list) or not robots:
        raise PlanningError(f"{name}: 'robots' must be a non-empty list")
    ids, starts, goals, paths = [], [], [], []
    for k, r in enumerate(robots):
        where = f"{name}: robot #{k}"
        if not isinstance(r, dict) or not all(f in r for f in ("id", "start", "goal", "path")):
            raise PlanningError(f"{where} lacks one of id, start, goal, path")
        if not isinstance(r["id"], int) or isinstance(r["id"], bool):
            raise PlanningError(f"{where}: id {r['id']!r} is not an integer")
        start = _cell(r["start"], f"{where} start", w, h)
        goal = _cell(r["goal"], f"{where} goal", w, h)
        if not isinstance(r["path"], list) or not r["path"]:
            raise PlanningError(f"{where}: path must be a non-empty list of [x, y]")
        path = [_cell(c, f"{where} path[{t}]", w, h) for t, c in enumerate(r["path"])]
        if path[0] != start or path[-1] != goal:
            raise PlanningError(f"{where}: path must run from its start {start} to its goal {goal}")
        ids.append(r["id"])
        starts.append(start)
        goals.append(goal)
        paths.append(path)
    if len(set(ids)) != len(ids):
        raise PlanningError(f"{name}: robot ids are not distinct")
    for key in ("metrics", "timings"):
        if not isinstance(d.get(key) or {}, dict):
            raise PlanningError(f"{name}: {key!r} must be an object")
    return LoadedPlan(free=free, ids=ids, starts=starts, goals=goals, paths=paths, connectivity=conn,
                      planner=str(d.get("planner", "")), map_name=str(m.get("name", "")),
                      metrics=dict(d.get("metrics") or {}), timings=dict(d.get("timings") or {}))


def read_plan(path: str | FsPath, validate: bool = True) -> LoadedPlan:
    """Load a plan file; with `validate`, also prove it collision-free (PlanningError if not)."""
    path = FsPath(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise PlanningError(f"plan file not found: {path}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise PlanningError(f"cannot read plan file {path}: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PlanningError(f"{path}: not JSON (line {exc.lineno}: {exc.msg})") from None
    except ValueError:  # an integer of more digits than Python converts
        raise PlanningError(f"{path}: not JSON (a number too long)") from None
    except RecursionError:  # the parser recurses per level of nesting
        raise PlanningError(f"{path}: not a plan (JSON nested too deeply)") from None
    plan = plan_from_dict(data, str(path))
    if validate:
        check(plan.problem, plan.paths)
    return plan
