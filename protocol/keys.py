"""Key expressions: every key lives under one fleet prefix `uavr/<fleet>`."""
from __future__ import annotations

import re
import secrets
from dataclasses import dataclass
from typing import Sequence

from .bounds import MAX_ROBOT_ID, MAX_ROBOTS
from .errors import UavRobotsError

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

    @property
    def uav_pose(self) -> str:
        """The vehicle's pose (VehiclePose) about 5 times a second while it flies, for observers; no one must listen."""
        return f"{self.prefix}/uav/pose"

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

    def states_as(self, ids: Sequence[int]) -> str:
        """Where a pool puts the StateBatch of its robots `ids` (access control binds it to the pool)."""
        return f"{self.prefix}/robots/{format_ids(ids)}/states"

    @property
    def all_state_batches(self) -> str:
        return f"{self.prefix}/robots/*/states"

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

    def alive_observer(self, name: str) -> str:
        return f"{self.prefix}/alive/observer/{name}"

    @property
    def alive_observers(self) -> str:
        return f"{self.prefix}/alive/observer/*"

    # world services (queryables)
    @property
    def camera(self) -> str:
        return f"{self.prefix}/world/camera"

    @property
    def move(self) -> str:
        return f"{self.prefix}/world/move"

    def move_as(self, ids: Sequence[int]) -> str:
        """The move service asked by the robots `ids`, named in the key: access control lets an identity
        ask only under its own ids, and the world judges only moves of the robots the key names."""
        return f"{self.move}/{format_ids(ids)}"

    @property
    def moves_by_identity(self) -> str:
        return f"{self.move}/*"

    def ahead_as(self, ids: Sequence[int]) -> str:
        """Where the robots `ids` put their MoveAhead (a put, not a query; the key names who sends)."""
        return f"{self.prefix}/world/ahead/{format_ids(ids)}"

    @property
    def all_ahead(self) -> str:
        return f"{self.prefix}/world/ahead/*"

    def judged_as(self, ids: Sequence[int]) -> str:
        """Where the world puts the MovesJudged answering the MoveAhead of `ids` (the same label)."""
        return f"{self.prefix}/world/judged/{format_ids(ids)}"

    @property
    def world_info(self) -> str:
        return f"{self.prefix}/world/info"

    @property
    def record(self) -> str:
        return f"{self.prefix}/world/record"

    @property
    def world_movers(self) -> str:
        """The world's people, forklifts and pallets after each tick (FloorMovers): ground truth for
        observers (views, recorders). The UAV must not listen: it sees movers only through its camera."""
        return f"{self.prefix}/world/movers"


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


def format_ids(ids: Sequence[int]) -> str:
    """[0, 1, 2, 5] -> '0-2,5' (for log lines)."""
    out: list[str] = []
    ids = sorted(ids)
    i = 0
    while i < len(ids):
        j = i
        while j + 1 < len(ids) and ids[j + 1] == ids[j] + 1:
            j += 1
        out.append(str(ids[i]) if i == j else f"{ids[i]}-{ids[j]}")
        i = j + 1
    return ",".join(out)


def parse_ids(text: str) -> list[int]:
    """'0-3,7,10-11' -> [0, 1, 2, 3, 7, 10, 11]."""
    ids: set[int] = set()
    for part in filter(None, (p.strip() for p in text.split(","))):
        lo, sep, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise UavRobotsError(f"robot ids {text!r}: {part!r} is not a number or a range like 0-49") from None
        if a < 0 or b < a:
            raise UavRobotsError(f"robot ids {text!r}: {part!r} is not a range of non-negative ids")
        if b > MAX_ROBOT_ID or b - a + 1 + len(ids) > MAX_ROBOTS:
            raise UavRobotsError(f"robot ids {text!r}: at most {MAX_ROBOTS} robots with ids up to {MAX_ROBOT_ID}")
        ids.update(range(a, b + 1))
    if not ids:
        raise UavRobotsError(f"robot ids {text!r}: no id given")
    return sorted(ids)


MAX_IDS_LABEL = 4096   # characters of a move key's robot ids: bounded before parsing


def _ids_of_label(what: str, key: str, label: str) -> list[int]:
    if len(label) > MAX_IDS_LABEL:
        raise UavRobotsError(f"{what} key {key[:80]!r}...: its robot ids are {len(label)} characters, "
                             f"more than {MAX_IDS_LABEL}")
    if not label:
        raise UavRobotsError(f"{what} key {key[:80]!r} does not name robot ids")
    return parse_ids(label)


def ids_of_states_key(keys: Keys, key: str) -> list[int]:
    """The robots a StateBatch's key names; UavRobotsError for a key that names no valid ids."""
    head, tail = f"{keys.prefix}/robots/", "/states"
    label = key[len(head):-len(tail)] if key.startswith(head) and key.endswith(tail) else ""
    return _ids_of_label("state batch", key, label)


def ids_of_move_key(keys: Keys, key: str) -> list[int] | None:
    """The robots a move query's key names: None for the plain `world/move` (no identity in the key).
    Raises UavRobotsError for a key that names no valid ids."""
    if key == keys.move:
        return None
    return _ids_of_label("move", key, key[len(keys.move) + 1:] if key.startswith(keys.move + "/") else "")


def ids_of_ahead_key(keys: Keys, key: str) -> list[int]:
    """The robots a MoveAhead's key names; UavRobotsError for a key that names no valid ids."""
    head = f"{keys.prefix}/world/ahead/"
    return _ids_of_label("move-ahead", key, key[len(head):] if key.startswith(head) else "")
