"""Checks of what a UAV under test sent, made after its mission from the world's record alone.

Pure functions, independent of our planners and validator: a plan (first or repair) is judged
against the world's truth and the cells its robots really stood on at the plan's start tick; the
status, pose and image streams against docs/protocol.md's keys table.
"""
from __future__ import annotations

from collections import deque
from typing import Any, Iterable

from protocol.grid import Cell, on_grid
from protocol.messages import CameraFrame, MissionStatus, Plan, Record, VehiclePose

# docs/protocol.md, Mission phases: in this order up to the first `executing`; then repairs and the
# verification, and `land` last.
PHASES = ("connecting", "takeoff", "survey", "perceive", "plan", "dispatch", "executing", "recover", "verify", "land")
EXECUTION_PHASES = {"executing", "recover", "dispatch", "verify"}
STATUS_EVERY = 10        # ticks between two `executing` statuses
PREVIEW_SIDE = 640       # px: the longer side of a `uav/frame` image at most
POSE_HZ = 5.0            # `uav/pose`: about this many a second ...
POSE_MIN_HZ = 2.0        # ... and never fewer than this many on average while flying (a loaded machine) ...
POSE_GAP_S = 2.0         # ... nor a gap longer than this


def cells_at(record: Record, tick: int) -> dict[int, Cell]:
    """Where the world had each robot after `tick` (its last cell if the record ends earlier)."""
    out = {}
    for rid, cells in record.executed.items():
        if cells:
            out[int(rid)] = tuple(cells[min(tick, len(cells) - 1)])
    return out


def _diagonal(a: Cell, b: Cell) -> bool:
    return abs(a[0] - b[0]) == 1 and abs(a[1] - b[1]) == 1


def _step_problem(free: Any, a: Cell, b: Cell, connectivity: int) -> str:
    dx, dy = abs(b[0] - a[0]), abs(b[1] - a[1])
    if connectivity == 4 and dx + dy > 1 or max(dx, dy) > 1:
        return f"{a} -> {b} is not a {connectivity}-connected move"
    if _diagonal(a, b) and not (free[a[1], b[0]] and free[b[1], a[0]]):
        return f"{a} -> {b} cuts a corner"
    return ""


def plan_problems(plans: dict[int, Plan], start: int, truth: Any, record: Record, connectivity: int) -> list[str]:
    """Why the plans put under one plan_id (robot -> its plan) are not one executable plan from tick `start`:
    each path starts on the cell its robot really stood on after `start` (the world's record), moves between
    adjacent free cells, keeps off the cells of the robots left out of it (they stay where they stood), and
    ends on its goal, a goal marker no other robot of the plan has; no two robots share a cell at a tick,
    swap cells or cross diagonals."""
    problems: list[str] = []
    h, w = truth.free.shape
    where = cells_at(record, start)
    out_of_plan = {c for r, c in where.items() if r not in plans}
    goals = {tuple(g) for g in truth.goals}
    for rid, plan in sorted(plans.items()):
        path = [tuple(c) for c in plan.path]
        if plan.start_tick != start:
            problems.append(f"robot {rid}: start_tick {plan.start_tick}, the plan's others start at {start}")
        if not path:
            problems.append(f"robot {rid}: an empty path")
            continue
        if rid in where and path[0] != where[rid]:
            problems.append(f"robot {rid}: the path starts at {path[0]}, the robot stood on {where[rid]} after "
                            f"tick {start}")
        for i, (x, y) in enumerate(path):
            if not on_grid(x, y, w, h) or not truth.free[y, x]:
                problems.append(f"robot {rid}: path cell {i} {(x, y)} is not free floor")
                break
            if (x, y) in out_of_plan:
                problems.append(f"robot {rid}: path cell {i} {(x, y)} is where a robot out of the plan stands")
                break
            if i and (why := _step_problem(truth.free, path[i - 1], (x, y), connectivity)):
                problems.append(f"robot {rid}: step {i} {why}")
                break
        if path[-1] != tuple(plan.goal) or tuple(plan.goal) not in goals:
            problems.append(f"robot {rid}: the path ends at {path[-1]}, its goal is {tuple(plan.goal)} "
                            f"({'a goal marker' if tuple(plan.goal) in goals else 'no goal marker'})")
    owners: dict[Cell, int] = {}
    for rid, plan in sorted(plans.items()):
        other = owners.setdefault(tuple(plan.goal), rid)
        if other != rid:
            problems.append(f"robots {other} and {rid} have the same goal {tuple(plan.goal)}")
    problems += conflicts({r: [tuple(c) for c in p.path] for r, p in plans.items() if p.path}, start)
    return problems


def conflicts(paths: dict[int, list[Cell]], start: int = 0) -> list[str]:
    """Vertex (a goal reached counts: a robot stays on its last cell), swap and diagonal-crossing conflicts."""
    out: list[str] = []
    horizon = max((len(p) for p in paths.values()), default=0)
    at = lambda p, t: p[min(t, len(p) - 1)]  # noqa: E731
    ids = sorted(paths)
    for t in range(horizon):
        seen: dict[Cell, int] = {}
        for r in ids:
            c = at(paths[r], t)
            if c in seen:
                out.append(f"robots {seen[c]} and {r} are both on {c} at tick {start + t}")
            seen.setdefault(c, r)
        if t == 0:
            continue
        for i, a in enumerate(ids):
            for b in ids[i + 1:]:
                a0, a1, b0, b1 = at(paths[a], t - 1), at(paths[a], t), at(paths[b], t - 1), at(paths[b], t)
                if a0 == b1 and b0 == a1 and a0 != a1:
                    out.append(f"robots {a} and {b} swap {a0} and {b0} at tick {start + t}")
                elif (_diagonal(a0, a1) and _diagonal(b0, b1)
                      and (a0[0] + a1[0], a0[1] + a1[1]) == (b0[0] + b1[0], b0[1] + b1[1])):
                    out.append(f"robots {a} and {b} cross diagonals at tick {start + t}")
        if len(out) > 20:
            break
    return out


def can_reach_a_goal(truth: Any, cell: Cell, walls: set[Cell], goals: Iterable[Cell]) -> bool:
    """Whether a free goal is reachable from `cell` (4-connected), the `walls` cells blocked."""
    targets = {tuple(g) for g in goals} - walls
    h, w = truth.free.shape
    todo, seen = deque([tuple(cell)]), {tuple(cell)}
    while todo:
        x, y = todo.popleft()
        if (x, y) in targets:
            return True
        for n in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
            if n not in seen and on_grid(n[0], n[1], w, h) and truth.free[n[1], n[0]] and n not in walls:
                seen.add(n)
                todo.append(n)
    return False


def phase_problems(statuses: list[MissionStatus], fleet: int, last_tick: int) -> list[str]:
    """docs/protocol.md, Mission phases: in order, `executing` every 10 ticks up to `last_tick` (the last Tick
    put) with its fields, `land` last."""
    problems = []
    phases = [s.phase for s in statuses]
    unknown = sorted(set(phases) - set(PHASES))
    if unknown:
        problems.append(f"phases not in the document: {unknown}")
    first_exec = phases.index("executing") if "executing" in phases else len(phases)
    before = [PHASES.index(p) for p in phases[:first_exec] if p in PHASES]
    if before != sorted(before):
        problems.append(f"phases out of order before execution: {phases[:first_exec]}")
    later = [p for p in phases[first_exec:] if p not in EXECUTION_PHASES and p != "land"]
    if later:
        problems.append(f"phases {sorted(set(later))} after execution began")
    if "land" in phases and any(p != "land" for p in phases[phases.index("land"):]):
        problems.append(f"phases after land: {phases[phases.index('land'):]}")
    if "land" in phases and "verify" not in phases:
        problems.append("land without a verify before it")
    execs = [s for s in statuses if s.phase == "executing"]
    for s in execs:
        if s.robots != fleet or not 0 <= s.done <= s.robots or (s.tick and s.ticks < 1):
            problems.append(f"an executing status with robots {s.robots}, done {s.done}, ticks {s.ticks} "
                            f"(the fleet has {fleet} robots)")
            break
    told = {s.tick for s in execs}
    missing = [k for k in range(STATUS_EVERY, last_tick + 1, STATUS_EVERY) if k not in told]
    if missing:
        problems.append(f"no executing status for tick(s) {missing[:5]} (every {STATUS_EVERY} ticks)")
    return problems


def pose_problems(poses: list[tuple[float, VehiclePose]], took_off: float | None) -> list[str]:
    """`uav/pose`: about 5 a second from take-off until landed."""
    if not poses:
        return ["no VehiclePose on uav/pose"]
    problems = []
    times = [t for t, _ in poses]
    flying = [(t, p) for t, p in poses if p.in_air]
    if not flying:
        problems.append("no pose shows the vehicle in the air")
    else:
        span = flying[-1][0] - flying[0][0]
        rate = (len(flying) - 1) / span if span > 0 else 0.0
        if rate < POSE_MIN_HZ or rate > 3 * POSE_HZ:
            problems.append(f"{rate:.1f} poses a second while flying, not about {POSE_HZ:g}")
        gap = max((b - a for a, b in zip(times, times[1:])), default=0.0)
        if gap > POSE_GAP_S:
            problems.append(f"a gap of {gap:.1f} s between two poses")
    if took_off is not None and times[0] > took_off:
        problems.append("the pose stream began after the take-off")
    if poses[-1][1].in_air:
        problems.append("the last pose shows the vehicle still in the air: the stream ended before it landed")
    return problems


def frame_problems(frames: list[tuple[float, CameraFrame]], sent: list[dict[str, Any]], end: float | None) -> list[str]:
    """`uav/frame`: each a JPEG of at most 640 px, one of the UAV's images (its pose and time kept) with the
    intrinsics scaled to its size, before MissionEnd."""
    import cv2
    import numpy as np

    if not frames:
        return ["no CameraFrame on uav/frame"]
    problems = []
    by_time = {round(float(s["time_s"]), 6): s for s in sent if "time_s" in s}
    for t, f in frames:
        name = f"the frame of time_s {f.time_s}"
        if f.encoding != "jpeg":
            problems.append(f"{name} is {f.encoding}, not jpeg")
        if max(f.width, f.height) > PREVIEW_SIDE:
            problems.append(f"{name} is {f.width}x{f.height}, more than {PREVIEW_SIDE} px")
        image = cv2.imdecode(np.frombuffer(f.png, np.uint8), cv2.IMREAD_UNCHANGED) if f.png else None
        if image is None or image.shape[:2] != (f.height, f.width):
            problems.append(f"{name}: its image does not decode to {f.width}x{f.height}")
        src = by_time.get(round(f.time_s, 6))
        if src is None:
            problems.append(f"{name} matches no image the world took (a frame keeps its image's pose and time)")
        else:
            sx, sy = f.width / src["width"], f.height / src["height"]
            off = max(abs(f.fx - src["fx"] * sx), abs(f.fy - src["fy"] * sy),
                      abs(f.cx - src["cx"] * sx), abs(f.cy - src["cy"] * sy))
            if off > 1.0:
                problems.append(f"{name}: intrinsics ({f.fx:.1f}, {f.fy:.1f}, {f.cx:.1f}, {f.cy:.1f}) are not the "
                                f"image's scaled by {sx:.3f} x {sy:.3f}")
        if end is not None and t > end:
            problems.append(f"{name} came after MissionEnd")
        if len(problems) > 5:
            break
    return problems
