"""The moves the planners allow on a grid, shared by the reference planners.

A robot waits or moves to a free neighbour: 4-connected, or 8-connected without cutting a
corner (a diagonal needs both cells beside it free). Two robots never share a cell, never
swap cells, and never move across the same 2x2 square diagonally at once (the validator's
rules, `planning/validator.py`).
"""
from __future__ import annotations

from collections import deque

import numpy as np

from ..types import Cell

STRAIGHT = ((1, 0), (-1, 0), (0, 1), (0, -1))
DIAGONAL = ((1, 1), (1, -1), (-1, 1), (-1, -1))


def neighbours(free: np.ndarray, c: Cell, connectivity: int) -> list[Cell]:
    h, w = free.shape
    x, y = c
    out = []
    for dx, dy in STRAIGHT + (DIAGONAL if connectivity == 8 else ()):
        nx, ny = x + dx, y + dy
        if not (0 <= nx < w and 0 <= ny < h and free[ny, nx]):
            continue
        if dx and dy and not (free[y, nx] and free[ny, x]):
            continue
        out.append((nx, ny))
    return out


def distances_to(free: np.ndarray, goal: Cell, connectivity: int) -> dict[Cell, int]:
    """Steps from every cell that reaches `goal` (breadth-first, backwards from it)."""
    dist = {goal: 0}
    queue = deque([goal])
    while queue:
        c = queue.popleft()
        for n in neighbours(free, c, connectivity):
            if n not in dist:
                dist[n] = dist[c] + 1
                queue.append(n)
    return dist


def crosses(a_from: Cell, a_to: Cell, b_from: Cell, b_to: Cell) -> bool:
    """True when two diagonal moves cross the same 2x2 square (the other diagonal of it)."""
    if abs(a_to[0] - a_from[0]) != 1 or abs(a_to[1] - a_from[1]) != 1:
        return False
    return b_from == (a_to[0], a_from[1]) and b_to == (a_from[0], a_to[1]) or \
        b_from == (a_from[0], a_to[1]) and b_to == (a_to[0], a_from[1])


def configurations_to_paths(history: list[tuple[Cell, ...]], goals: list[Cell]) -> list[list[Cell]]:
    """One path per robot from a sequence of configurations, each cut after its last arrival."""
    paths = []
    for i, goal in enumerate(goals):
        path = [q[i] for q in history]
        while len(path) > 1 and path[-1] == goal and path[-2] == goal:
            path.pop()
        paths.append(path)
    return paths
