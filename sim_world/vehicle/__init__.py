"""A PX4-SITL-like multicopter autopilot, speaking MAVLink 2 through pymavlink.

No real PX4 or ArduPilot SITL can be installed here, so this is the vehicle MAVSDK,
MAVProxy and pymavlink clients fly. It implements what a ground station needs from
a PX4 autopilot (see the project's transport notes): heartbeats with PX4 custom
modes, the parameter protocol, REQUEST_MESSAGE / SET_MESSAGE_INTERVAL, telemetry
streams, COMMAND_ACK for every command, arm / takeoff / land / DO_REPOSITION /
DO_SET_MODE and offboard position or velocity setpoints.

The physics is kinematic and runs on simulated time (`time_scale` simulated seconds
per wall second); the link (heartbeats, telemetry rates, the offboard setpoint
timeout) runs on wall time, since that is what the ground station's own timeouts use.

The parts, each owning its state under the vehicle's one lock:
- `dynamics`: the airframe (position, velocity, yaw), its physics step, the land detector;
  `motion`: the motion laws a step follows (speed, acceleration and jerk limits);
- `autopilot`: arming, flight modes, auto-disarm; it flies the airframe (`guidance`: the target of
  each mode; `safety`: the failsafes and preflight checks);
- `offboard`: the offboard setpoint stream; `params`: parameters and their protocol;
- `telemetry`: message builders and streams; `commands`: message and MAV_CMD dispatch tables;
- `link`: the MAVLink connection; `journal`: events and warnings; `vehicle`: the facade.
"""
from .config import VehicleConfig
from .modes import LandedState, Mode
from .motion import step_toward, step_yaw
from .vehicle import Vehicle

__all__ = ["LandedState", "Mode", "Vehicle", "VehicleConfig", "step_toward", "step_yaw"]
