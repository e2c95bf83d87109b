"""What the UAV is told to do: its fleet, its links, its planner and its limits."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..camera_source.base import CameraSourceConfig


@dataclass
class MissionConfig:
    fleet: str
    robots: int | None = None               # expected fleet size; None = as many as the camera sees
    listen: list[str] = field(default_factory=list)   # hub mode: be the Zenoh router
    connect: list[str] = field(default_factory=list)  # or join an existing router
    zenoh_config: str | None = None
    mavlink_url: str = "udpin://0.0.0.0:14540"
    planner: str | None = None
    assign: str = "optimal"
    connectivity: int = 4
    time_limit_s: float = 60.0
    fallback: bool = True
    seed: int = 0
    out: Path | None = None
    startup_timeout_s: float = 30.0
    observers: int = 0                 # wait (OBSERVER_WAIT_S at most) for this many recorders before the first status
    tick_timeout_s: float = 10.0
    tick_rate_hz: float = 0.0          # at most this many ticks per second (0: as fast as the fleet goes)
    monitor_every: int | None = None   # an image every this many ticks while robots move (0: never; None: auto)
    look_every: int | None = None      # movers: a look every this many ticks (0: never; None: once the survey saw one)
    # A robot's marker module is 1/8 cell: 19 px per cell gives 2.4 px per module, which reads
    # through the realistic camera (at 17.5, 5 of the 450 warehouse's 50 robots went unread);
    # on the 450 floor with a 4000x3000 camera it is also where 3 x 3 images cover it, not 4 x 3.
    min_px_per_cell: float = 19.0
    camera: CameraSourceConfig = field(default_factory=CameraSourceConfig)   # where the images come from
    run: dict | None = None            # the run's spec (run.json), copied into the report: it repeats the run
