"""Faults on demand, so that tests and demos can check how the UAV detects and repairs them.

    crash:ROBOT@TICK         the robot dies when tick TICK arrives (a lone robot's process exits at once;
                             a robot in a pool vanishes from the network, its pool lives on)
    stall:ROBOT@TICK:TICKS   from tick TICK the robot neither moves nor reports, until tick TICK+TICKS
    liar:ROBOT               the robot raises Done as soon as it has a plan, and then never moves or reports

Ticks count the UAV's clock (the `k` of `Tick`), so a stall ends when the rest of the
fleet has moved on that far, however long the UAV held it.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from protocol.errors import UavRobotsError

_FORMS = {
    "crash": re.compile(r"crash:(\d+)@(\d+)$"),
    "stall": re.compile(r"stall:(\d+)@(\d+):(\d+)$"),
    "liar": re.compile(r"liar:(\d+)$"),
}
USAGE = "crash:ROBOT@TICK, stall:ROBOT@TICK:TICKS or liar:ROBOT"


@dataclass(frozen=True)
class Fault:
    kind: str
    robot: int
    tick: int = 0
    ticks: int = 0

    def __str__(self) -> str:
        return {"crash": f"crash:{self.robot}@{self.tick}", "stall": f"stall:{self.robot}@{self.tick}:{self.ticks}",
                "liar": f"liar:{self.robot}"}[self.kind]

    def silent_at(self, k: int) -> bool:
        """True while the robot must neither move nor report at tick k."""
        if self.kind == "liar":
            return True
        if self.kind == "stall":
            return self.tick <= k < self.tick + self.ticks
        return False


def parse_fault(text: str) -> Fault:
    """One robot fault; `slip:PROB` is the world's (see sim_world), not a robot's."""
    for kind, form in _FORMS.items():
        m = form.match(text.strip())
        if m:
            nums = [int(g) for g in m.groups()]
            if kind != "liar" and nums[1] < 1:
                raise UavRobotsError(f"--fault {text!r}: ticks start at 1")
            if kind == "stall" and nums[2] < 1:
                raise UavRobotsError(f"--fault {text!r}: a stall lasts at least one tick")
            return Fault(kind, *nums)
    raise UavRobotsError(f"--fault {text!r}: give {USAGE}")
