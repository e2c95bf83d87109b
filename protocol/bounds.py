"""The bounds of every message field: the limits, and the annotations that carry them.

Every number that sizes a receiver's memory or work is bounded when a message is decoded
(protocol/codec.py); the message catalogue (protocol/messages.py) writes its fields with the
bounded types below, and the decoder, the size limits and the JSON Schemas (protocol/schemas.py)
are all derived from those annotations.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Annotated, Any, get_origin

from . import grid

# Limits: every number that sizes a receiver's memory or work is bounded when a message is
# decoded. docs/protocol.md repeats them for other implementations.
# Each type's JSON text is at most its own limit (json_limit): the longest its bounded fields can
# write plus MARGIN_BYTES for optional fields a newer sender adds, and never more than its cap.
MAX_MESSAGE_BYTES = 8 * 2**20    # the cap of every type but Record's (a full MoveBatchResult fits)
MAX_RECORD_BYTES = 128 * 2**20   # Record's cap: it holds every robot's executed path
MARGIN_BYTES = 4_096             # room for fields this side does not know, in every type's limit
MAX_IMAGE_BYTES = 64 * 2**20     # a CameraFrame's PNG, after the NUL
MAX_DEPTH = 32                   # nested arrays and objects, the message's own object included
MAX_COUNT = 2**53 - 1            # seq and counters: the largest integer every JSON reader holds exactly
MAX_ROBOT_ID = 9_999_999         # seven decimal digits, also as Record.executed's keys
MAX_MOVERS = 1_000               # people, forklifts and pallets on one floor (FloorMovers)
MAX_ROBOTS = 65_536              # entries of a MoveBatch, a MoveBatchResult, Record.executed
MAX_TICKS = 100_000              # tick numbers and makespans
MAX_PATH_CELLS = MAX_TICKS + 1   # a planned or executed path: one cell per tick from 0
MAX_GRID_SIDE = grid.MAX_GRID_SIDE  # cells per floor row or column (kept in grid.py: maps check it too)
MAX_IMAGE_SIDE = 16_384          # camera image width and height, pixels
MAX_TEXT_CHARS = 4_096           # any string
MAX_REFUSED = 1_000_000          # entries of Record.refused
MAX_KEYS = 256                   # keys of a free-form object (Record.truth, an entry of Record.refused)
MAX_LANDMARKS = 65_536           # entries of WorldInfo.landmarks
MAX_FLOAT = sys.float_info.max


@dataclass(frozen=True)
class Range:
    """A number's inclusive bounds; `open_lo` excludes the lower one (a positive float)."""
    lo: int | float
    hi: int | float
    open_lo: bool = False


@dataclass(frozen=True)
class MaxLen:
    """At most `n` characters of a string, items of an array, keys of an object or bytes of a binary tail."""
    n: int


@dataclass(frozen=True)
class Pattern:
    """A string's whole text matches `regex` (written so that JSON Schema reads it the same)."""
    regex: str


Count = Annotated[int, Range(0, MAX_COUNT)]
RobotId = Annotated[int, Range(0, MAX_ROBOT_ID)]
RobotKey = Annotated[str, MaxLen(len(str(MAX_ROBOT_ID))), Pattern("0|[1-9][0-9]*")]  # an id as str(id) writes it
Robots = Annotated[int, Range(0, MAX_ROBOTS)]
TickNo = Annotated[int, Range(0, MAX_TICKS)]
Coord = Annotated[int, Range(0, MAX_GRID_SIDE - 1)]
Cell = tuple[Coord, Coord]  # protocol.grid.Cell with bounded coordinates
Path = Annotated[list[Cell], MaxLen(MAX_PATH_CELLS)]
Text = Annotated[str, MaxLen(MAX_TEXT_CHARS)]
Finite = Annotated[float, Range(-MAX_FLOAT, MAX_FLOAT)]
Positive = Annotated[float, Range(0.0, MAX_FLOAT, open_lo=True)]
Object = Annotated[dict[Text, Any], MaxLen(MAX_KEYS)]
NonNegative = Annotated[float, Range(0.0, MAX_FLOAT)]


def unwrap(tp: Any) -> tuple[Any, tuple[Any, ...]]:
    """Annotated[T, *bounds] -> (T, bounds); any other type -> (it, ())."""
    if get_origin(tp) is Annotated:
        return tp.__origin__, tp.__metadata__
    return tp, ()


def bound(meta: tuple[Any, ...], kind: type) -> Any:
    return next((m for m in meta if isinstance(m, kind)), None)

