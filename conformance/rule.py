"""A rule of docs/protocol.md that a robot or a UAV must keep, and the protocol sections rules come from."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Rule:
    id: str                 # R<n> (robots) or U<n> (UAVs)
    section: str            # the docs/protocol.md section it comes from
    text: str               # the rule, as an implementer reads it
    tests: tuple[str, ...]  # test functions (pytest -k names) of the side's suite that check it
    mutant: str             # how the rule's mutant (conformance.mutants) breaks it
    since: int = 1          # the protocol version that introduced it (docs/protocol.md, Versioning)

    @property
    def side(self) -> str:
        return "robot" if self.id.startswith("R") else "uav"


S, K, M, P, F, E = ("Startup order", "Keys", "Messages", "Plans and ticks", "Faults and recovery", "End of mission")
W = "Timeouts and waits"
