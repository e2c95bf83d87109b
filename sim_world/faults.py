"""The world's executor of the faults the catalogue (protocol/faults.py) gives the world: slip:P (any
move ends elsewhere with probability P) and skid:ROBOT@TICK (from tick TICK every move of that robot
ends elsewhere: a broken drive that keeps deviating). The move judge (`moves.py`) applies them."""
from __future__ import annotations

from dataclasses import dataclass, field

from protocol.faults import WORLD, parse_fault


@dataclass(frozen=True)
class WorldFaults:
    slip: float = 0.0                                       # every move, with this probability
    skids: dict[int, int] = field(default_factory=dict)     # robot -> the tick from which every move skids


def world_faults(specs: list[str]) -> WorldFaults:
    """The world's faults of `specs`; one line for a spec the world does not inject."""
    slip, skids = 0.0, {}
    for f in (parse_fault(s, WORLD) for s in specs):
        if f.kind == "skid":
            skids[f.robot] = f.tick
        elif f.kind == "slip":
            slip = f.p
    return WorldFaults(slip, skids)
