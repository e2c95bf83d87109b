"""PX4's flight modes as the heartbeat carries them, and MAVLink's landed states."""
from __future__ import annotations

import enum


class Mode(enum.Enum):
    """PX4 flight modes as (main mode, sub mode) of the heartbeat's custom_mode."""

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    READY = (4, 1)
    TAKEOFF = (4, 2)
    HOLD = (4, 3)  # AUTO.LOITER
    MISSION = (4, 4)
    RTL = (4, 5)
    LAND = (4, 6)
    ACRO = (5, 0)
    OFFBOARD = (6, 0)
    STABILIZED = (7, 0)

    @property
    def custom_mode(self) -> int:
        main, sub = self.value
        return (main << 16) | (sub << 24)

    @classmethod
    def from_custom_mode(cls, main: int, sub: int) -> "Mode | None":
        for mode in cls:
            if mode.value == (main, sub):
                return mode
        return None


# The heartbeat's base mode marks these as autonomous (AUTO_ENABLED), as PX4 does.
AUTO_MODES = (Mode.READY, Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.RTL, Mode.LAND)


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE values, as sent in EXTENDED_SYS_STATE."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKING_OFF = 3
    LANDING = 4
