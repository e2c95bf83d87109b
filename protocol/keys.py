"""Key expressions: every key lives under one fleet prefix `uavr/<fleet>`."""
from __future__ import annotations

import re
import secrets
from dataclasses import dataclass

from .errors import UavRobotsError
from .messages import MAX_ROBOT_ID

ROOT = "uavr"
ROBOT_ID_DIGITS = len(str(MAX_ROBOT_ID))
_FLEET_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


DEFAULT_FLEET = "default"   # the fleet of parts started alone without --fleet, as a SITL is


def new_fleet_name() -> str:
    return "f" + secrets.token_hex(4)


@dataclass(frozen=True)
class Keys:
    fleet: str

    def __post_init__(self) -> None:
        if not _FLEET_RE.match(self.fleet):
            raise UavRobotsError(f"fleet name {self.fleet!r} must be 1-64 of A-Z a-z 0-9 _ -")

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.fleet}"

    # UAV -> robots
    def plan(self, robot: int) -> str:
        return f"{self.prefix}/robot/{robot}/plan"

    @property
    def tick(self) -> str:
        return f"{self.prefix}/tick"

    @property
    def mission_status(self) -> str:
        return f"{self.prefix}/mission/status"

    @property
    def mission_end(self) -> str:
        return f"{self.prefix}/mission/end"

    @property
    def mission_event(self) -> str:
        return f"{self.prefix}/mission/event"

    @property
    def uav_frame(self) -> str:
        """Every image the UAV takes, downscaled to JPEG, for observers (views, recorders); no one must listen."""
        return f"{self.prefix}/uav/frame"

    # robots -> UAV
    def ack(self, robot: int) -> str:
        return f"{self.prefix}/robot/{robot}/ack"

    def state(self, robot: int) -> str:
        return f"{self.prefix}/robot/{robot}/state"

    def done(self, robot: int) -> str:
        return f"{self.prefix}/robot/{robot}/done"

    @property
    def all_acks(self) -> str:
        return f"{self.prefix}/robot/*/ack"

    @property
    def all_states(self) -> str:
        return f"{self.prefix}/robot/*/state"

    @property
    def all_done(self) -> str:
        return f"{self.prefix}/robot/*/done"

    # liveliness
    def alive_robot(self, robot: int) -> str:
        return f"{self.prefix}/alive/robot/{robot}"

    @property
    def alive_robots(self) -> str:
        return f"{self.prefix}/alive/robot/*"

    @property
    def alive_world(self) -> str:
        return f"{self.prefix}/alive/world"

    @property
    def alive_uav(self) -> str:
        return f"{self.prefix}/alive/uav"

    # world services (queryables)
    @property
    def camera(self) -> str:
        return f"{self.prefix}/world/camera"

    @property
    def move(self) -> str:
        return f"{self.prefix}/world/move"

    @property
    def world_info(self) -> str:
        return f"{self.prefix}/world/info"

    @property
    def record(self) -> str:
        return f"{self.prefix}/world/record"


def robot_id_from_key(key: str) -> int | None:
    """`.../robot/<id>/...` or `.../alive/robot/<id>` -> id, None if the key has no valid id.

    Only the id as `Keys` writes it counts: not '²' (a digit to `isdigit`, not to `int`), '007', or
    more digits than a robot id has (`int` refuses thousands of them with ValueError)."""
    parts = key.split("/")
    for i, p in enumerate(parts[:-1]):
        text = parts[i + 1]
        if (p == "robot" and text.isascii() and text.isdigit() and len(text) <= ROBOT_ID_DIGITS
                and str(int(text)) == text):
            return int(text)
    return None
