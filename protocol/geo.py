"""Local NED metres <-> WGS84 latitude/longitude, and grid cells <-> NED.

Conventions (shared by the vehicle, the camera and the UAV agent):

* The local NED origin is the warehouse grid's top-left corner (the outer corner of
  cell (0, 0)); it is also the vehicle's home, at ground level (down = 0).
* north = -y (up the image), east = +x. The centre of grid cell (x, y), with square
  cells of `cell_m` metres, is at east = (x + 0.5) * cell_m, north = -(y + 0.5) * cell_m.
  So the whole floor lies at north <= 0, east >= 0.
* Geodetic conversion is a flat-earth (equirectangular) projection around the home
  point. A warehouse spans well under a kilometre, where its error against a proper
  geodesic is centimetres; what matters more is that both sides of the MAVLink link
  use these same two functions, so that a point converted there and back is exact.
"""
from __future__ import annotations

import math

from .errors import MissionError

EARTH_RADIUS_M = 6378137.0  # WGS84 equatorial radius, as PX4's local projection uses
MAX_ABS_LAT_DEG = 85.0  # the projection's east scale, cos(lat), degenerates at the poles


def check_home(home_lat: float, home_lon: float) -> None:
    """Raise MissionError unless (home_lat, home_lon) is a usable projection origin."""
    if not (math.isfinite(home_lat) and math.isfinite(home_lon)):
        raise MissionError(f"home position ({home_lat}, {home_lon}) is not a finite latitude/longitude")
    if abs(home_lat) > MAX_ABS_LAT_DEG:
        raise MissionError(f"home latitude {home_lat} is outside [-{MAX_ABS_LAT_DEG}, {MAX_ABS_LAT_DEG}] degrees")
    if abs(home_lon) > 180.0:
        raise MissionError(f"home longitude {home_lon} is outside [-180, 180] degrees")


def _wrap_deg(angle: float) -> float:
    """Wrap an angle in degrees to [-180, 180)."""
    return (angle + 180.0) % 360.0 - 180.0


def ned_to_geo(north: float, east: float, home_lat: float, home_lon: float) -> tuple[float, float]:
    """Local (north, east) metres from home -> (latitude, longitude) in degrees."""
    check_home(home_lat, home_lon)
    lat = home_lat + math.degrees(north / EARTH_RADIUS_M)
    lon = home_lon + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(home_lat))))
    return lat, _wrap_deg(lon)


def geo_to_ned(lat: float, lon: float, home_lat: float, home_lon: float) -> tuple[float, float]:
    """(latitude, longitude) in degrees -> local (north, east) metres from home."""
    check_home(home_lat, home_lon)
    north = math.radians(lat - home_lat) * EARTH_RADIUS_M
    east = math.radians(_wrap_deg(lon - home_lon)) * EARTH_RADIUS_M * math.cos(math.radians(home_lat))
    return north, east


def cell_to_ned(x: float, y: float, cell_m: float) -> tuple[float, float]:
    """Centre of grid cell (x, y) -> (north, east) metres. Fractional cells are fine."""
    return -(y + 0.5) * cell_m, (x + 0.5) * cell_m


def ned_to_cell(north: float, east: float, cell_m: float) -> tuple[int, int]:
    """(north, east) metres -> the grid cell (x, y) containing that point (may be off-grid)."""
    return math.floor(east / cell_m), math.floor(-north / cell_m)
