"""The world's geodetic helpers live in protocol/geo.py, shared with the UAV agent
(which must not import sim_world); this module re-exports them for sim_world code."""
from protocol.geo import EARTH_RADIUS_M, cell_to_ned, check_home, geo_to_ned, ned_to_cell, ned_to_geo

__all__ = ["EARTH_RADIUS_M", "cell_to_ned", "check_home", "geo_to_ned", "ned_to_cell", "ned_to_geo"]
