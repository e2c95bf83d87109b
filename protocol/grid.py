"""Grid cells as every part writes them: `(x, y)`, x the column, y the row, origin top-left (MovingAI)."""
from __future__ import annotations

Cell = tuple[int, int]

MAX_GRID_SIDE = 16_384   # cells per floor row or column; coordinates are 0 .. MAX_GRID_SIDE - 1


def on_grid(x: int, y: int, width: int, height: int) -> bool:
    return 0 <= x < width and 0 <= y < height
