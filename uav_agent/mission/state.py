"""What a mission knows as it goes, in parts: the plan flown, who is out of it, what the camera
confirmed, the survey's vantage and the phase clock. Plain records: the phases change them."""
from __future__ import annotations

import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from protocol.grid import Cell
from protocol.messages import CameraFrame

if TYPE_CHECKING:
    from ..shots import Shots

SURVEY_SPEED_M_S = 20.0    # asked of the autopilot for the flight between hover poses (capped by MPC_XY_VEL_MAX)


class Clock:
    """Wall seconds per phase, summed over its laps (a mission may repair and verify several times)."""

    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, phase: str) -> None:
        now = time.perf_counter()
        self.add(phase, now - self._t)
        self._t = now

    def add(self, phase: str, seconds: float) -> None:
        self.timings[phase] = round(self.timings.get(phase, 0.0) + seconds, 4)


@dataclass
class PlanState:
    """The plan the fleet executes now: robot r is at paths[r][i] at tick start_tick + i."""
    plan_id: str
    start_tick: int
    paths: dict[int, list[Cell]]
    goals: dict[int, Cell]

    @property
    def ids(self) -> list[int]:
        return sorted(self.paths)

    @property
    def end_tick(self) -> int:
        return self.start_tick + max(len(p) for p in self.paths.values()) - 1

    def cell(self, robot: int, tick: int) -> Cell:
        path = self.paths[robot]
        return tuple(path[min(max(tick - self.start_tick, 0), len(path) - 1)])


@dataclass
class Plans:
    """The floor as perceived, the first plan and the one flown now."""
    model: Any = None                       # perception's WorldModel of the survey
    free: Any = None                        # its free cells (numpy bool, [y, x])
    ids: list[int] = field(default_factory=list)   # the robots planned for, in plan order
    first: Any = None                       # the first PlanResult (report.json's plan)
    now: PlanState | None = None
    goal_of: dict[int, Cell] = field(default_factory=dict)   # each robot's goal in the last plan it was part of
    unserved: list[Cell] = field(default_factory=list)


@dataclass
class Roster:
    """Robots out of the plan, and the faults that may put them there."""
    blocked: dict[int, Cell] = field(default_factory=dict)       # out of the plan (lost, stalled, faulty) -> its cell
    blocked_at: dict[int, float] = field(default_factory=dict)   # when each was taken out (a later sign of life brings it back)
    out_reason: dict[int, str] = field(default_factory=dict)     # why each robot out of the plan is out
    quarantined: dict[int, str] = field(default_factory=dict)    # out for good (kept failing, or had no goal left)
    strikes: dict[int, list[str]] = field(default_factory=dict)  # faults since last shown on its plan ("deviation@9")
    clean_moves: dict[int, int] = field(default_factory=dict)    # robot with strikes -> planned moves kept in a row since
    fruitless: int = 0                       # repairs in a row that brought the fleet no nearer its goals
    best_lb: tuple[frozenset[int], float] | None = None   # (working robots, best lower bound)
    fruitless_culprits: set[int] = field(default_factory=set)
    replans: int = 0

    def take_out(self, robot: int, cell: Cell) -> None:
        self.blocked[robot] = tuple(cell)
        self.blocked_at[robot] = time.monotonic()

    def bring_back(self, robot: int) -> None:
        self.blocked.pop(robot, None)
        self.blocked_at.pop(robot, None)
        self.out_reason.pop(robot, None)

    def forgive(self, robots) -> None:
        """Robots shown on their plan start afresh (an image, or two clean moves in a row)."""
        for r in robots:
            self.strikes.pop(r, None)
            self.clean_moves.pop(r, None)


@dataclass
class Glance:
    """A monitoring image, perceived off the tick loop, and what it shows once it is."""
    plan_id: str
    tick: int
    shots: "Shots | None" = None
    off: list[int] | None = None       # robots off their planned cell at `tick`; None until judged
    on_plan: list[int] = field(default_factory=list)   # robots on their planned cell at `tick`
    on_goal: list[int] = field(default_factory=list)   # robots on their goals after their last move
    took: float = 0.0                  # wall seconds from the request to the judgement


@dataclass
class Arrivals:
    """What the camera confirmed, and the images still to take or being perceived for it."""
    verified: dict[int, bool] = field(default_factory=dict)
    confirmed: dict[int, str] = field(default_factory=dict)   # robot -> the plan under which an image after its last move showed it on its goal
    contradicted: set[int] = field(default_factory=set)      # robots whose Done an image denied (said once)
    seen_at_end: dict[int, Cell] = field(default_factory=dict)
    stops: list = field(default_factory=list)   # arrival_tour.Stop: poses still to shoot for arrivals ...
    stop: Any = None                            # ... and the one the vehicle flies to or holds at
    arrived_at: int | None = None               # the attitude sample current when the vehicle was seen at it
    ticks: dict[int, int] = field(default_factory=dict)   # robot -> the tick of its last move in the plan flown
    glances: list[Glance] = field(default_factory=list)   # monitoring images being perceived, oldest first
    monitor_work: float = 0.0                   # wall seconds the monitoring images took, off the tick loop
    monitored: int = 0
    exec_t0: float = 0.0                        # when execution (re)started, and at which tick
    exec_k0: int = 0


@dataclass
class Vantage:
    """The survey's poses and what follows from them: where the vehicle hovers, how fast it flies."""
    calibration: CameraFrame | None = None   # the camera's intrinsics and lens (an image without pixels)
    border: Future | None = None             # the survey's image border, worked out while the link comes up
    poses: list[tuple[float, float, float]] = field(default_factory=list)
    hover: tuple[float, float, float] | None = None   # (north, east, altitude) over the floor's centre
    alt: float = 0.0                         # the survey's highest altitude
    heading: float = 0.0                     # the vehicle's kept heading when it flies no goto's yaw
    fusion: Any = None                       # the survey's perception.Fusion
    # The vehicle's speed from pose to pose in wall time, stopping and levelling included:
    # measured by the survey, then by each hop between arrival stops.
    speed_m_s: float = SURVEY_SPEED_M_S
    flown_m: float = 0.0
    flown_s: float = 0.0
    hop: tuple[float, float] | None = None   # (when, metres) of the hop to the arrival stop flown to

    def flew(self, metres: float, seconds: float) -> None:
        self.flown_m += metres
        self.flown_s += seconds
        self.speed_m_s = max(1.0, self.flown_m / self.flown_s)


@dataclass
class Compile:
    """The planners' kernels on a fresh clone: compiled by a process of their own during the flight,
    the plan meanwhile made by the same planners interpreted."""
    compiling: bool = False                  # the kernels were not cached when the mission began
    warm: threading.Thread | None = None     # compiles (if need be) and loads them
    skip_warm: threading.Event = field(default_factory=threading.Event)   # planned without them: do not load
    interpreter: Any = None                  # interpreted.InterpretedPlanner started ahead, serving once
