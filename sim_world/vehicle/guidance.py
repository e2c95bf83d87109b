"""The autopilot's guidance: the target each flight mode flies to (offboard, mission, return to launch).

A part of `Autopilot` (autopilot.py), kept apart from its arming and mode changes; its methods
run under the vehicle's lock from `Autopilot.setpoint`, and read and set the autopilot's state.
"""
from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from .dynamics import Dynamics
from .geofence import Geofence
from .journal import WARNING, Journal
from .mission import Item, Leg, Mission
from .motion import Vec3
from .offboard import Offboard
from .params import Params
from .payload import Payload

TAKEOFF_DONE_M = 0.1  # takeoff ends within this distance of the takeoff altitude
RTL_HOME_M = 0.3  # RTL lands once this close to home horizontally


class Guidance:
    """Where the autopilot flies in OFFBOARD, MISSION and RTL; mixed into Autopilot."""

    # The autopilot's parts and state these methods use (Autopilot.__init__ sets them).
    _journal: Journal
    _dynamics: Dynamics
    _params: Params
    _offboard: Offboard
    _mission: Mission
    _fence: Geofence
    _payload: Payload | None
    _target: Vec3
    _velocity: tuple | None
    _target_yaw: float
    _speed_xy: float
    _landing: bool
    _rtl_phase: str
    _rtl_alt: float
    _clamping: bool

    def _offboard_target(self, wall_now: float, dt: float, speed: float, up: float, down: float) -> None:
        if self._offboard.lost(wall_now):
            self._journal.event("offboard setpoints lost")
            self._enter_hold("offboard setpoints lost")
            return
        here, vel = self._position(), self._dynamics.state().vel
        command = self._offboard.command(self._target, vel, dt, speed, up, down)
        if command is not None:
            target, velocity = command
            if velocity is not None:
                # where the velocity would carry the vehicle before it could stop: kept inside the fence
                lookahead = math.hypot(*(v or 0.0 for v in velocity)) / max(self._params.get("MPC_ACC_HOR"), 0.1)
                ahead = tuple(h + (v or 0.0) * lookahead for h, v in zip(here, velocity))
                if self._fence.violation(ahead) is not None:
                    target, velocity = self._fenced(ahead), None
            self._target = self._fenced(target)
            self._velocity = velocity
        yaw = self._offboard.yaw(self._target_yaw, dt)
        if yaw is not None:
            self._target_yaw = yaw

    def _fenced(self, target: Vec3) -> Vec3:
        """An offboard target pulled back onto the geofence, said once per stretch of clamping."""
        outside = self._fence.violation(target)
        if outside is None:
            self._clamping = False
            return target
        if not self._clamping:
            self._journal.say(WARNING, f"Offboard target outside the geofence ({outside}): held at the fence")
            self._clamping = True
        return self._fence.clamp(target)

    def _mission_target(self, here: Vec3, airborne: bool, speed: float) -> float:
        step = self._mission.steer(here, airborne, self._dynamics.sim_time, self._act)
        if step is None:
            if not airborne:
                self._disarm_soon()
            return min(self._speed_xy, self._params.get("MPC_XY_VEL_MAX"))  # an item may have changed it
        if step.leg is Leg.RETURN:
            self.rtl("mission")
            return speed
        speed = min(self._speed_xy, self._params.get("MPC_XY_VEL_MAX"))
        if step.leg is Leg.HOLD:
            return speed
        self._target = step.target
        if step.leg is Leg.LAND:
            self._landing = True
            return 0.0
        return 0.0 if step.leg is Leg.CLIMB else speed

    def _rtl_target(self, here: Vec3, speed: float) -> float:
        n, e, _ = here
        if self._rtl_phase == "climb":
            self._target = (n, e, -self._rtl_alt)
            if self._dynamics.altitude >= self._rtl_alt - TAKEOFF_DONE_M:
                self._rtl_phase = "return"
            else:
                return 0.0
        if self._rtl_phase == "return":
            self._target = (0.0, 0.0, -self._rtl_alt)
            if math.hypot(n, e) <= RTL_HOME_M:
                self._rtl_phase = "land"
                self._journal.event("RTL: landing at home")
            return speed
        self._target = (0.0, 0.0, 0.0)
        self._landing = True
        return speed

    def _act(self, item: Item) -> None:
        """A mission's DO item, reached: the speed is the autopilot's, the camera and gimbal the payload's."""
        if item.command == mavlink.MAV_CMD_DO_CHANGE_SPEED:
            self.change_speed(int(item.param1) if math.isfinite(item.param1) else 1, item.param2)
        elif self._payload is not None:
            self._payload.on_item(item.command, (item.param1, item.param2, item.param3, item.param4, item.x, item.y,
                                                 item.z), self._position(), self._dynamics.sim_time)
