"""The battery budget of a flight: does the vehicle have the time for it, and to land after?

Pure. The autopilot says how long its pack lasts at the current draw (BATTERY_STATUS.time_remaining,
in its own seconds: a simulator's run faster than the wall); a flight of hover poses costs its legs at
a speed the autopilot surely reaches, flying fast draws more than a hover, each pose a stop to brake,
level and shoot, and the landing its descent. A quarter of what is left is kept to return and land
(PX4 warns at 15 % and acts at 7 %: a plan that ends there has already failed).
"""
from __future__ import annotations

import math

RESERVE = 0.25            # of the time left, never planned for
BUDGET_SPEED_M_S = 10.0   # below PX4's MPC_XY_VEL_MAX default (12): the survey asks 20, the autopilot may cap it
FAST_DRAW = 1.4           # flying at speed draws this much more than a hover
STOP_S = 5.0              # brake, level and shoot at each pose
DESCENT_M_S = 0.7         # PX4's MPC_LAND_SPEED


def flight_seconds(poses: list[tuple[float, float, float]], start: tuple[float, float, float]) -> float:
    """Seconds (the autopilot's) to fly from `start` (north, east, altitude) through `poses` and land
    after the last."""
    legs = 0.0
    here = start
    for pose in poses:
        legs += math.dist(here, pose)
        here = pose
    return legs / BUDGET_SPEED_M_S * FAST_DRAW + STOP_S * len(poses) + here[2] / DESCENT_M_S


def shortfall(time_left_s: float | None, need_s: float, what: str, pct: float = -1.0) -> str | None:
    """Why `what` must not be flown (None: it may, or the autopilot says nothing to budget with)."""
    if time_left_s is None or not math.isfinite(time_left_s) or time_left_s <= 0:
        return None
    usable = time_left_s * (1.0 - RESERVE)
    if need_s <= usable:
        return None
    charge = f" ({pct:.0f} %)" if pct >= 0 else ""
    return (f"battery: {time_left_s / 60:.1f} min of flight left{charge}; {what} needs about {need_s / 60:.1f} min "
            f"and {RESERVE:.0%} is kept to return and land: not flown")
