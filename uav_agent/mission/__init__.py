"""The UAV's mission: take off -> survey -> perceive -> plan -> dispatch -> step -> land -> report.

Phases (one module each) over one `MissionContext`, around pure parts: `flight` (MAVLink),
`perception` (OpenCV), `planning` (assignment, paths, validator), `fleet` (the robots over
Zenoh). The UAV never reads the world's ground truth; it asks the world's record only after
the mission, to score it.
"""
from .config import MissionConfig
from .context import MissionContext
from .phases import run_mission

__all__ = ["MissionConfig", "MissionContext", "run_mission"]
