"""Where an aborted mission lands: off the floor, never over the fleet.

Pure. Landing where the vehicle hovers puts it down among the robots (the issue saw every abort do
so); beyond the floor's nearest corner, a few cells out each way, nothing of the mission stands.
"""
from __future__ import annotations

import math

OFF_FLOOR_CELLS = 3     # beyond the corner, this many cells out each way
MIN_ALT_M = 3.0         # flown there at least this high


def abort_spot(north: float, east: float, alt: float, width: int, height: int,
               cell_size_m: float) -> tuple[float, float, float]:
    """(north, east, altitude) to fly to before landing, from the vehicle at (north, east, alt) over a
    floor of `width` x `height` cells whose top-left corner is the frame's origin (rows go south)."""
    off = OFF_FLOOR_CELLS * cell_size_m
    corners = [(n, e) for n in (off, -height * cell_size_m - off) for e in (-off, width * cell_size_m + off)]
    n, e = min(corners, key=lambda p: math.hypot(p[0] - north, p[1] - east))
    return n, e, max(alt, MIN_ALT_M)
