"""The faults the world injects into the robots' moves (`--fault slip:P`, `--fault skid:ROBOT@TICK`).

The launcher hands the world the --fault kinds named here and the robots the others.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from protocol.errors import UavRobotsError

WORLD_FAULTS = ("slip:", "skid:")   # the --fault kinds the world injects; the others are the robots'


def is_world_fault(spec: str) -> bool:
    return spec.strip().startswith(WORLD_FAULTS)


@dataclass(frozen=True)
class WorldFaults:
    slip: float = 0.0                                       # every move, with this probability
    skids: dict[int, int] = field(default_factory=dict)     # robot -> the tick from which every move skids


def world_faults(faults: list[str]) -> WorldFaults:
    """slip:P (any move ends elsewhere with probability P) and skid:ROBOT@TICK (from tick TICK every
    move of that robot ends elsewhere: a broken drive that keeps deviating); one line for a bad one."""
    slip, skids = 0.0, {}
    for f in faults:
        kind, _, value = f.strip().partition(":")
        if kind == "skid":
            robot, at, tick = value.partition("@")
            if not (robot.isdigit() and at and tick.isdigit() and int(tick) >= 1):
                raise UavRobotsError(f"--fault {f!r}: give skid:ROBOT@TICK (ticks start at 1)")
            skids[int(robot)] = int(tick)
            continue
        try:
            slip = float(value)
        except ValueError:
            slip = -1.0
        if kind != "slip" or not 0.0 <= slip <= 1.0:
            raise UavRobotsError(f"--fault {f!r}: the world takes slip:P with P in [0, 1] or skid:ROBOT@TICK")
    return WorldFaults(slip, skids)
