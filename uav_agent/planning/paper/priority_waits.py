"""The paper's collision avoidance by priority (Section 3.2.2): robots only ever wait.

Every robot keeps the cells of its own path. Priority goes to the longer path
(ties: the lower robot index). Robots are scheduled in priority order; a
lower-priority robot waits, before the point of collision, until every
higher-priority robot has passed it. That covers a single point of collision
(wait one step aside) and a run of shared cells passed head-on (wait before the
first of them until the other robot has left the last).

Where to wait is found by a depth-first search over (index on own path, step)
that may only advance or wait and always tries to advance first: a robot moves
on while it can and waits at the last safe cell before a conflict; if that cell
is itself run into while it waits, the search backs up and waits one cell
earlier. Each state is visited once, and after the last move of every
higher-priority robot the world is static, so the search is bounded by (path
length) x (that step) states and usually visits little more than the path. A robot arrives on its goal only
once no higher-priority robot needs the goal cell any more, because from then on
it sits there for good.

The method is incomplete: no amount of waiting helps a robot that meets a
higher-priority one head-on in a corridor, or whose path crosses a cell where a
higher-priority robot has parked on its goal. It then raises IncompleteError
naming the two robots and the cell.
"""
from __future__ import annotations

from protocol.errors import PlanningError

from ..types import Cell, Limits, Path, Problem


class IncompleteError(PlanningError):
    """Waiting cannot resolve a conflict; `.robots` = (waiting robot, robot in the way), `.cell`."""

    def __init__(self, message: str, robots: tuple[int, ...], cell: Cell | None):
        super().__init__(message)
        self.robots = robots
        self.cell = cell


class _Reservations:
    """The timed cells and moves of the robots scheduled so far (flat cell indices)."""

    def __init__(self, width: int, height: int):
        self.w = width
        self.size = width * height
        self.cells: dict[int, int] = {}        # t * size + cell -> robot
        self.moves: dict[int, int] = {}        # (t * size + from) * size + to -> robot (arriving at t)
        self.parked: dict[int, tuple[int, int]] = {}   # goal cell -> (robot, from step)
        self.last_use: dict[int, int] = {}     # cell -> last step a robot stands on it before parking
        self.end = 0                           # after this step nothing moves any more

    def add(self, robot: int, timed: list[int]) -> None:
        size = self.size
        prev = timed[0]
        for t, c in enumerate(timed):
            self.cells[t * size + c] = robot
            if c != prev:
                self.moves[(t * size + prev) * size + c] = robot
            if self.last_use.get(c, -1) < t:
                self.last_use[c] = t
            prev = c
        self.parked[timed[-1]] = (robot, len(timed) - 1)
        self.end = max(self.end, len(timed) - 1)

    def at(self, c: int, t: int) -> int:
        """The robot on cell c at step t, or -1."""
        r = self.cells.get(t * self.size + c, -1)
        if r < 0:
            p = self.parked.get(c)
            if p is not None and t >= p[1]:
                return p[0]
        return r

    def edge(self, a: int, b: int, t: int) -> int:
        """The robot whose move at step t collides with a move a -> b: a swap or a diagonal crossing."""
        size = self.size
        r = self.moves.get((t * size + b) * size + a, -1)
        if r >= 0:
            return r
        w = self.w
        ax, ay, bx, by = a % w, a // w, b % w, b // w
        if ax != bx and ay != by:
            c, d = ay * w + bx, by * w + ax      # the other diagonal of the same 2x2 square
            r = self.moves.get((t * size + c) * size + d, -1)
            if r < 0:
                r = self.moves.get((t * size + d) * size + c, -1)
        return r


def _schedule(robot: int, path: list[int], res: _Reservations, limits: Limits | None) -> list[int]:
    """The robot's path with waits inserted so that it avoids every robot in `res`."""
    last = len(path) - 1
    goal = path[-1]
    if goal in res.parked:
        other = res.parked[goal][0]
        raise IncompleteError(f"robots {other} and {robot} have the same goal {_xy(goal, res.w)}",
                              (robot, other), _xy(goal, res.w))
    free_after = res.last_use.get(goal, -1)   # arrive later than this, or be run into
    first = res.at(path[0], 0)
    if first >= 0:
        raise IncompleteError(f"robots {first} and {robot} both start on {_xy(path[0], res.w)}",
                              (robot, first), _xy(path[0], res.w))
    # cells ahead that a parked robot blocks for good: beyond res.end only they matter
    parked_ahead = [-1] * (last + 2)
    for k in range(last, -1, -1):
        parked_ahead[k] = k if path[k] in res.parked else parked_ahead[k + 1]

    stride = res.end + last + 2
    parent: dict[int, int] = {0: -1}
    stack = [(0, 0)]                          # (step, index); depth first, advancing before waiting
    blocked = (-1, -1, 0)                     # deepest failed advance: (index, robot in the way, cell)
    pops = 0
    while stack:
        t, k = stack.pop()
        pops += 1
        if limits is not None and pops % 2048 == 0:
            limits.check(f"priority waits for robot {robot}")
        if k == last and t > free_after:
            return _unwind(parent, k * stride + t, stride, path)
        if t >= res.end:
            # nothing moves any more: go straight on unless a parked robot is in the way
            ahead = parked_ahead[k + 1] if k < last else -1
            if ahead < 0:
                key = k * stride + t
                for j in range(k + 1, last + 1):
                    nxt = j * stride + t + j - k
                    parent[nxt] = key
                    key = nxt
                return _unwind(parent, key, stride, path)
            if ahead > blocked[0]:
                blocked = (ahead, res.parked[path[ahead]][0], path[ahead])
            continue
        key = k * stride + t
        nxt = key + 1
        if nxt not in parent:
            who = res.at(path[k], t + 1)
            if who < 0:
                parent[nxt] = key
                stack.append((t + 1, k))
            elif k >= blocked[0]:
                blocked = (k, who, path[k])
        if k < last:
            nxt = (k + 1) * stride + t + 1
            if nxt not in parent:
                who = res.at(path[k + 1], t + 1)
                if who < 0 and path[k + 1] != path[k]:
                    who = res.edge(path[k], path[k + 1], t + 1)
                if who < 0:
                    parent[nxt] = key
                    stack.append((t + 1, k + 1))
                elif k + 1 >= blocked[0]:
                    blocked = (k + 1, who, path[k + 1])
    k, other, cell = blocked
    xy = _xy(cell, res.w)
    if res.parked.get(cell, (-1,))[0] == other:
        why = f"robot {other} sits on its goal {xy}, on robot {robot}'s path"
    else:
        why = f"waiting cannot let robot {other} pass {xy} (e.g. head-on in a corridor)"
    raise IncompleteError(f"priority waits cannot resolve robot {robot}: {why}", (robot, other), xy)


def _unwind(parent: dict[int, int], key: int, stride: int, path: list[int]) -> list[int]:
    out = []
    while key >= 0:
        out.append(path[key // stride])
        key = parent[key]
    out.reverse()
    return out


def _xy(c: int, w: int) -> Cell:
    return (c % w, c // w)


def priority_waits(problem: Problem, paths: list[Path], limits: Limits | None = None) -> list[Path]:
    """Individual paths (one per robot) -> a conflict-free plan that only adds waits."""
    h, w = problem.free.shape
    if len(paths) != problem.n:
        raise PlanningError(f"priority waits: {len(paths)} paths for {problem.n} robots")
    flat: list[list[int]] = []
    for i, p in enumerate(paths):
        if not p:
            raise PlanningError(f"priority waits: robot {i} has no path")
        if tuple(p[0]) != tuple(problem.starts[i]) or tuple(p[-1]) != tuple(problem.goals[i]):
            raise PlanningError(f"priority waits: robot {i}'s path does not run from its start to its goal")
        flat.append([int(y) * w + int(x) for x, y in p])
    order = sorted(range(problem.n), key=lambda i: (-len(flat[i]), i))
    res = _Reservations(w, h)
    out: list[Path] = [[] for _ in range(problem.n)]
    for i in order:
        if limits is not None:
            limits.check("priority waits")
        timed = _schedule(i, flat[i], res, limits)
        res.add(i, timed)
        out[i] = [(c % w, c // w) for c in timed]
    return out
