"""What the fake fleet keeps: each robot's own state, and everything the UAV sent and the fleet answered."""
from __future__ import annotations

from dataclasses import dataclass, field

from protocol.grid import Cell
from protocol.messages import (CameraFrame, Done, MissionEnd, MissionEvent, MissionStatus, Plan, PlanAck, RobotState,
                               Tick, VehiclePose)
from protocol.transport import Handle


@dataclass
class FakeRobot:
    rid: int
    cell: Cell
    token: Handle | None = None
    plan: Plan | None = None
    base: int = 0                       # plan.path[i] is the cell at tick base + i
    acked: dict[str, bool] = field(default_factory=dict)   # plan_id -> ok
    sent: set[str] = field(default_factory=set)            # plan_ids the UAV sent this robot
    reported: set[int] = field(default_factory=set)        # ticks whose RobotState was put
    done_for: str = ""
    last_state: RobotState | None = None
    seq: int = 0
    gone: bool = False                  # its token vanished for good (lost): it does nothing any more
    frozen: int = 0                     # ticks of a stall still to sit out
    deviated: bool = False              # its one deviation is behind it
    ignored_repair: str = ""            # the repair plan it ignores every put of


@dataclass
class Observed:
    """What the UAV sent and what the fleet answered, in arrival order, with monotonic times."""
    plans: list[tuple[float, int, Plan, bool]] = field(default_factory=list)  # time, key's robot, plan, token up
    ticks: list[tuple[float, Tick]] = field(default_factory=list)
    statuses: list[tuple[float, MissionStatus]] = field(default_factory=list)
    events: list[tuple[float, MissionEvent]] = field(default_factory=list)
    poses: list[tuple[float, VehiclePose]] = field(default_factory=list)
    frames: list[tuple[float, CameraFrame]] = field(default_factory=list)
    ends: list[tuple[float, MissionEnd]] = field(default_factory=list)
    uav_alive: list[tuple[float, bool]] = field(default_factory=list)
    seqs: list[tuple[str, int]] = field(default_factory=list)          # (kind, seq) of every UAV message
    acks: list[tuple[float, PlanAck]] = field(default_factory=list)
    dones: list[tuple[float, Done]] = field(default_factory=list)
    joined: dict[int, float] = field(default_factory=dict)              # robot -> when its token went up
    # What the harness did wrong on purpose: (kind, robot, tick, time), e.g. ("lost", 2, 4, t) for a
    # robot whose token vanished after its state of tick 4 was put.
    faults: list[tuple[str, int, int, float]] = field(default_factory=list)
    violations: list[tuple[str, str]] = field(default_factory=list)    # (kind, text): the UAV broke the contract
    harness: list[str] = field(default_factory=list)                    # the suite's own trouble (world silent)

    @property
    def first_status(self) -> float | None:
        """When the UAV's first status came."""
        return self.statuses[0][0] if self.statuses else None

    def of(self, *kinds: str) -> list[str]:
        return [text for kind, text in self.violations if kind in kinds]

    def fault(self, kind: str, robot: int | None = None) -> tuple[str, int, int, float] | None:
        """The first fault of `kind` the harness made (of `robot`, if given)."""
        return next((f for f in self.faults if f[0] == kind and robot in (None, f[1])), None)

    def __repr__(self) -> str:  # short: pytest prints it in every failed assertion that mentions it
        return (f"Observed({len(self.plans)} plans, {len(self.ticks)} ticks, {len(self.ends)} ends, "
                f"{len(self.acks)} acks, {len(self.dones)} dones, {len(self.faults)} faults, "
                f"{len(self.violations)} violations)")
