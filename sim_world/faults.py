"""The world's executor of the faults the catalogue (protocol/faults.py) gives the world: slip:P (any
move ends elsewhere with probability P) and skid:ROBOT@TICK (from tick TICK every move of that robot
ends elsewhere: a broken drive that keeps deviating), which the move judge (`moves.py`) applies; and
the camera's camera-off and camera-stuck windows, which `camera_faults.py` applies to its answers."""
from __future__ import annotations

from dataclasses import dataclass, field

from protocol.faults import WORLD, parse_fault

from .camera_faults import CameraFaults, camera_faults


@dataclass(frozen=True)
class WorldFaults:
    slip: float = 0.0                                       # every move, with this probability
    skids: dict[int, int] = field(default_factory=dict)     # robot -> the tick from which every move skids
    camera: CameraFaults | None = None                      # the camera's windows, None: none


def world_faults(specs: list[str]) -> WorldFaults:
    """The world's faults of `specs`; one line for a spec the world does not inject."""
    slip, skids = 0.0, {}
    for f in (parse_fault(s, WORLD) for s in specs):
        if f.kind == "skid":
            skids[f.robot] = f.tick
        elif f.kind == "slip":
            slip = f.p
    return WorldFaults(slip, skids, camera_faults(specs))
