"""The wire contract shared by the UAV, the world and the robots."""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from .errors import MapError, MissionError, PlanningError, ProtocolError, UavRobotsError

if TYPE_CHECKING:
    from .codec import decode, encode
    from .keys import Keys, new_fleet_name
    from .messages import PROTOCOL_VERSION, SCHEMA_VERSION

__all__ = ["Keys", "MapError", "MissionError", "PROTOCOL_VERSION", "PlanningError", "ProtocolError",
           "SCHEMA_VERSION", "UavRobotsError", "decode", "encode", "new_fleet_name"]

# Imported on first use: every command imports this package (its errors, the process life cycle),
# and `uav-robots plan` needs neither the key expressions nor the message classes.
_LAZY = {"Keys": "keys", "new_fleet_name": "keys", "PROTOCOL_VERSION": "messages", "SCHEMA_VERSION": "messages",
         "decode": "codec", "encode": "codec"}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
