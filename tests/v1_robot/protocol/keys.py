"""Key expressions: every key lives under one fleet prefix `uavr/<fleet>`."""
from __future__ import annotations

import re
import secrets
from dataclasses import dataclass

from .errors import UavRobotsError

ROOT = "uavr"
_FLEET_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


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
    """`.../robot/<id>/...` or `.../alive/robot/<id>` -> id, None if the key has no valid id."""
    parts = key.split("/")
    for i, p in enumerate(parts[:-1]):
        if p == "robot" and parts[i + 1].isdigit():
            return int(parts[i + 1])
    return None
