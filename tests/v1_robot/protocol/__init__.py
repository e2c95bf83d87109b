"""The wire contract shared by the UAV, the world and the robots."""
from .errors import MapError, MissionError, PlanningError, ProtocolError, UavRobotsError
from .keys import Keys, new_fleet_name
from .messages import PROTOCOL_VERSION, decode, encode

__all__ = ["Keys", "MapError", "MissionError", "PROTOCOL_VERSION", "PlanningError", "ProtocolError",
           "UavRobotsError", "decode", "encode", "new_fleet_name"]
