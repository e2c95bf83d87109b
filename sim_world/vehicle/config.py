"""How a simulated vehicle is reached and how it flies."""
from __future__ import annotations

import math
from dataclasses import dataclass

from protocol.errors import MissionError
from protocol.geo import check_home


@dataclass(frozen=True)
class VehicleConfig:
    """How the simulated vehicle is reached and how it flies.

    `url` is a pymavlink connection string: `udpout:host:port` sends to a ground
    station listening there (like PX4 SITL's offboard link on 14540),
    `udpin:host:port` listens and answers whoever sends valid MAVLink to it
    (port 0 picks a free port; see `Vehicle.local_address`).
    """

    url: str = "udpout:127.0.0.1:14540"
    system_id: int = 1
    home_lat: float = 47.397742  # PX4 SITL's default home (Zurich)
    home_lon: float = 8.545594
    home_alt_m: float = 488.0  # AMSL
    max_speed_m_s: float = 12.0
    max_climb_m_s: float = 3.0
    time_scale: float = 1.0
    takeoff_alt_m: float = 10.0  # MIS_TAKEOFF_ALT
    max_alt_m: float = 120.0
    land_speed_m_s: float = 0.7  # MPC_LAND_SPEED, used for the last metres of a landing
    disarm_after_land_s: float = 2.0  # COM_DISARM_LAND, simulated seconds
    hover_wobble_deg: float = 0.0  # amplitude of the roll/pitch wobble in the air (see dynamics.Wobble)
    seed: int = 0                  # of the wobble

    def __post_init__(self) -> None:
        check_home(self.home_lat, self.home_lon)
        if not 1 <= self.system_id <= 255:
            raise MissionError(f"vehicle system id {self.system_id} is outside 1..255")
        for name in ("max_speed_m_s", "max_climb_m_s", "time_scale", "takeoff_alt_m", "max_alt_m",
                     "land_speed_m_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise MissionError(f"vehicle {name} must be a positive number, got {value}")
        if not (math.isfinite(self.home_alt_m) and math.isfinite(self.disarm_after_land_s)
                and self.disarm_after_land_s >= 0):
            raise MissionError("vehicle home_alt_m and disarm_after_land_s must be finite (the latter >= 0)")
        if not (math.isfinite(self.hover_wobble_deg) and 0 <= self.hover_wobble_deg <= 30):
            raise MissionError(f"vehicle hover_wobble_deg must be in [0, 30], got {self.hover_wobble_deg}")
        if self.takeoff_alt_m > self.max_alt_m:
            raise MissionError(f"vehicle takeoff_alt_m {self.takeoff_alt_m} is above max_alt_m {self.max_alt_m}")
