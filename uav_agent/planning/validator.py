"""An independent check of a multi-robot plan: every rule a plan must obey, vectorised.

It shares no code with any planner on purpose: a planner's bug must not be
mirrored here. Paths are padded to a common horizon with their last cell (a
robot that has arrived stays on its goal and still blocks it), then every rule
is a numpy expression over the (robots x steps) arrays, so 1000 robots x 1000
steps take a fraction of a second.

Kinds of violation:
  length         no path, a wrong number of paths, a wrong start or a wrong last cell
  off-grid       a cell outside the map
  obstacle       a cell on an obstacle
  jump           a move to a non-neighbour, a diagonal in 4-connectivity, or a corner cut
  vertex         two robots in one cell at one step
  goal-occupied  a robot enters a cell where another robot already sits for good on its goal
  swap           two robots exchange cells in one step
  crossing       two diagonal moves across the same 2x2 square in one step (8-connectivity)
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import chain
import numpy as np

from protocol.errors import PlanningError

from .types import Cell, Path, Problem

_KIND_ORDER = {k: i for i, k in enumerate(
    ("length", "off-grid", "obstacle", "jump", "vertex", "goal-occupied", "swap", "crossing"))}


@dataclass(frozen=True)
class Violation:
    kind: str
    robots: tuple[int, ...]
    step: int
    cell: Cell | None
    text: str


def _flatten(paths: list[Path], out: list[Violation]) -> tuple[np.ndarray, list[int]]:
    """All well-formed paths as one int64 (cells, 2) array, and the robots they belong to.

    One `fromiter` over every coordinate is several times faster than a numpy
    conversion per path; only when the coordinate count is off are paths looked
    at one by one to name the malformed ones.
    """
    good = [i for i, p in enumerate(paths) if p is not None and len(p) > 0]
    for i, p in enumerate(paths):
        if p is None or len(p) == 0:
            out.append(Violation("length", (i,), 0, None, f"robot {i} has no path"))
    cells = sum(len(paths[i]) for i in good)
    try:
        flat = np.fromiter(chain.from_iterable(chain.from_iterable(paths[i] for i in good)), dtype=np.int64)
        if flat.size == 2 * cells:
            return flat.reshape(-1, 2), good
    except (TypeError, ValueError, OverflowError):
        pass
    ok, arrays = [], []
    for i in good:
        try:
            a = np.array(paths[i], dtype=np.int64)
        except (TypeError, ValueError, OverflowError):
            a = None
        if a is None or a.ndim != 2 or a.shape[1] != 2:
            out.append(Violation("length", (i,), 0, None,
                                 f"robot {i}: the path is not a list of (x, y) integer cells"))
        else:
            ok.append(i)
            arrays.append(a)
    return (np.concatenate(arrays) if arrays else np.zeros((0, 2), np.int64)), ok


def _pairs_in_runs(keys: np.ndarray, rows: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Groups of equal keys -> for each group, its key and member rows (only groups of 2+)."""
    if keys.size < 2 or not (np.diff(np.sort(keys)) == 0).any():
        return []                    # the common case: a valid plan has no repeated key
    order = np.argsort(keys, kind="stable")
    k = keys[order]
    dup = np.flatnonzero(k[1:] == k[:-1])
    starts = np.unique(np.searchsorted(k, k[dup], side="left"))
    ends = np.searchsorted(k, k[starts], side="right")
    return [(k[s], rows[order[s:e]]) for s, e in zip(starts, ends)]


def validate(problem: Problem, paths: list[Path]) -> list[Violation]:
    """Every violation of the plan, earliest step first."""
    free = np.asarray(problem.free, dtype=bool)
    h, w = free.shape
    n = problem.n
    if problem.connectivity not in (4, 8):
        raise PlanningError(f"connectivity must be 4 or 8, got {problem.connectivity}")
    out: list[Violation] = []
    if paths is None or len(paths) != n:
        got = "no paths" if paths is None else f"{len(paths)} paths"
        return [Violation("length", (), 0, None, f"{got} for {n} robots")]
    if n == 0:
        return []

    flat, good = _flatten(paths, out)
    if not good:
        return _sorted(out)
    robots = np.asarray(good, dtype=np.int64)
    lengths = np.fromiter((len(paths[i]) for i in good), dtype=np.int64, count=len(good))
    offsets = np.concatenate(([0], np.cumsum(lengths)[:-1]))
    horizon = int(lengths.max())
    t = np.arange(horizon, dtype=np.int64)
    idx = offsets[:, None] + np.minimum(t[None, :], lengths[:, None] - 1)
    X, Y = flat[idx, 0], flat[idx, 1]               # (robots, steps), padded with the last cell
    real = t[None, :] < lengths[:, None]            # False on the padding after a path ends
    for r, i in enumerate(good):
        first, last = (int(X[r, 0]), int(Y[r, 0])), (int(X[r, -1]), int(Y[r, -1]))
        s = (int(problem.starts[i][0]), int(problem.starts[i][1]))
        g = (int(problem.goals[i][0]), int(problem.goals[i][1]))
        if first != s:
            out.append(Violation("length", (i,), 0, first, f"robot {i} starts at {first}, not at its start {s}"))
        if last != g:
            out.append(Violation("length", (i,), int(lengths[r]) - 1, last,
                                 f"robot {i} ends at {last}, not at its goal {g}"))

    on = (X >= 0) & (X < w) & (Y >= 0) & (Y < h)
    for r, s in zip(*np.nonzero(~on & real)):
        c = (int(X[r, s]), int(Y[r, s]))
        out.append(Violation("off-grid", (int(robots[r]),), int(s), c,
                             f"robot {robots[r]} is off the {w}x{h} grid at {c} at step {s}"))
    Xc, Yc = np.clip(X, 0, w - 1), np.clip(Y, 0, h - 1)
    blocked = on & ~free[Yc, Xc] & real
    for r, s in zip(*np.nonzero(blocked)):
        c = (int(X[r, s]), int(Y[r, s]))
        out.append(Violation("obstacle", (int(robots[r]),), int(s), c,
                             f"robot {robots[r]} is on the obstacle {c} at step {s}"))

    cells = Yc * w + Xc
    cells = np.where(on, cells, -1)                 # off-grid cells take part in no conflict

    if horizon > 1:
        dx, dy = np.diff(X, axis=1), np.diff(Y, axis=1)
        both_on = on[:, 1:] & on[:, :-1]
        adx, ady = np.abs(dx), np.abs(dy)
        step_ok = (adx <= 1) & (ady <= 1)
        diag = (adx == 1) & (ady == 1)
        bad = ~step_ok
        if problem.connectivity == 4:
            bad |= diag
        else:
            x0, y0 = Xc[:, :-1], Yc[:, :-1]
            side_a = free[y0, np.clip(x0 + dx, 0, w - 1)]
            side_b = free[np.clip(y0 + dy, 0, h - 1), x0]
            bad |= diag & both_on & ~(side_a & side_b)
        for r, s in zip(*np.nonzero(bad)):
            a = (int(X[r, s]), int(Y[r, s]))
            b = (int(X[r, s + 1]), int(Y[r, s + 1]))
            why = ("a diagonal move in 4-connectivity" if problem.connectivity == 4 and diag[r, s]
                   else "a corner cut" if diag[r, s] else "not a move to a neighbour")
            out.append(Violation("jump", (int(robots[r]),), int(s + 1), b,
                                 f"robot {robots[r]} moves {a} -> {b} at step {s + 1}: {why}"))

    # a robot sits on its last cell for good from the step after its last move
    moved = (X != X[:, -1:]) | (Y != Y[:, -1:])
    settled = np.where(moved.any(axis=1), horizon - np.argmax(moved[:, ::-1], axis=1), 0)
    out += _vertex(cells, robots, settled, w)
    if horizon > 1:
        out += _swaps(cells, X, Y, robots, w, h)
        out += _crossings(X, Y, on, robots, w, h)
    return _sorted(out)


def _sorted(out: list[Violation]) -> list[Violation]:
    return sorted(out, key=lambda v: (v.step, _KIND_ORDER[v.kind], v.robots))


def _vertex(cells, robots, settled, w) -> list[Violation]:
    m, horizon = cells.shape
    size = np.int64(cells.max()) + 2
    keys = np.arange(horizon, dtype=np.int64)[None, :] * size + cells
    rows = np.repeat(np.arange(m, dtype=np.int64)[:, None], horizon, axis=1)
    mask = cells >= 0
    out = []
    for key, members in _pairs_in_runs(keys[mask], rows[mask]):
        step = int(key // size)
        c = int(key % size)
        cell = (c % w, c // w)
        ids = tuple(sorted(int(robots[r]) for r in members))
        parked = [int(robots[r]) for r in members if step > settled[r]]
        if parked:
            movers = [i for i in ids if i not in parked]
            out.append(Violation("goal-occupied", ids, step, cell,
                                 f"robot(s) {', '.join(map(str, movers or ids))} enter {cell} at step {step} "
                                 f"where robot {parked[0]} already sits on its goal"))
        else:
            out.append(Violation("vertex", ids, step, cell,
                                 f"robots {', '.join(map(str, ids))} share {cell} at step {step}"))
    return out


def _swaps(cells, X, Y, robots, w, h) -> list[Violation]:
    a, b = cells[:, :-1], cells[:, 1:]
    dx, dy = X[:, 1:] - X[:, :-1], Y[:, 1:] - Y[:, :-1]
    moving = (a >= 0) & (b >= 0) & (a != b) & (np.abs(dx) <= 1) & (np.abs(dy) <= 1)
    r, s = np.nonzero(moving)
    if r.size == 0:
        return []
    # an undirected edge at a step: its lower cell and the direction towards the higher one
    fwd = a[r, s] < b[r, s]
    low = np.where(fwd, a[r, s], b[r, s])
    sign = np.where(fwd, 1, -1)
    direction = (sign * dy[r, s] + 1) * 3 + (sign * dx[r, s] + 1)
    key = ((s + 1) * (np.int64(w) * h) + low) * 9 + direction
    out = []
    for _, members in _pairs_in_runs(key, np.arange(key.size)):
        ups = [m for m in members if fwd[m]]
        downs = [m for m in members if not fwd[m]]
        for i in ups:           # the same direction twice is a vertex conflict, reported there
            for j in downs:
                ids = tuple(sorted((int(robots[r[i]]), int(robots[r[j]]))))
                step = int(s[i] + 1)
                ca = (int(X[r[i], s[i]]), int(Y[r[i], s[i]]))
                cb = (int(X[r[i], s[i] + 1]), int(Y[r[i], s[i] + 1]))
                out.append(Violation("swap", ids, step, cb,
                                     f"robots {ids[0]} and {ids[1]} swap {ca} <-> {cb} at step {step}"))
    return out


def _crossings(X, Y, on, robots, w, h) -> list[Violation]:
    dx, dy = X[:, 1:] - X[:, :-1], Y[:, 1:] - Y[:, :-1]
    diag = (np.abs(dx) == 1) & (np.abs(dy) == 1) & on[:, 1:] & on[:, :-1]
    r, s = np.nonzero(diag)
    if r.size == 0:
        return []
    corner = np.minimum(Y[r, s], Y[r, s + 1]) * np.int64(w) + np.minimum(X[r, s], X[r, s + 1])
    key = (s + 1) * np.int64(w) * h + corner                 # one 2x2 square at one step
    main = dx[r, s] == dy[r, s]                             # "\" diagonal, else "/"
    out = []
    for kk, members in _pairs_in_runs(key, np.arange(key.size)):
        if main[members].all() or not main[members].any():
            continue        # same diagonal: a swap or a vertex conflict, reported as such
        ones = [int(robots[r[m]]) for m in members if main[m]]
        others = [int(robots[r[m]]) for m in members if not main[m]]
        step = int(kk // (np.int64(w) * h))
        c = int(kk % (np.int64(w) * h))
        cell = (c % w, c // w)
        for i in ones:
            for j in others:
                ids = tuple(sorted((i, j)))
                out.append(Violation("crossing", ids, step, cell,
                                     f"robots {ids[0]} and {ids[1]} cross diagonally in the 2x2 square "
                                     f"at {cell} at step {step}"))
    return out


def check(problem: Problem, paths: list[Path]) -> None:
    """Raise PlanningError naming the first violation and how many there are."""
    found = validate(problem, paths)
    if found:
        more = f" ({len(found)} violations in all)" if len(found) > 1 else ""
        raise PlanningError(f"invalid plan: {found[0].text}{more}")
