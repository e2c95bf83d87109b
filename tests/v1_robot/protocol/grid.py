"""Grid cells as every part writes them: `(x, y)`, x the column, y the row, origin top-left (MovingAI)."""
from __future__ import annotations

Cell = tuple[int, int]


def on_grid(x: int, y: int, width: int, height: int) -> bool:
    return 0 <= x < width and 0 <= y < height
