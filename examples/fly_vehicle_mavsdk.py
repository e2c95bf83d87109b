"""Start the simulated PX4-like vehicle and fly it with MAVSDK: connect, arm, take off, go somewhere, land.

    python3 examples/fly_vehicle_mavsdk.py

The vehicle (sim_world/vehicle) speaks MAVLink 2 as PX4 SITL does: it sends to a ground station's
UDP port, here a free one on loopback instead of 14540. MAVSDK's native 4.x binding (the `mavsdk`
package) flies it with the same calls as a real drone; `uav_agent/flight.py` wraps them for the UAV
agent. The vehicle runs 10 times faster than real time (`time_scale`), as `uav-robots run` flies it.
"""
from __future__ import annotations

import math
import socket
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # the checkout, even without `pip install -e .`

from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.logging import LogLevel, log_subscribe
from mavsdk.plugins.action import Action
from mavsdk.plugins.telemetry import LandedState, Telemetry

from protocol.geo import geo_to_ned, ned_to_geo
from sim_world.vehicle import Vehicle, VehicleConfig

ALTITUDE_M, NORTH_M, EAST_M = 10.0, -20.0, 15.0      # where to fly, in metres from home (north-east-down)


def wait_for(what: str, done, timeout_s: float) -> None:
    """Poll `done()` until it is true; RuntimeError after `timeout_s` seconds (wall clock)."""
    deadline = time.monotonic() + timeout_s
    while not done():
        if time.monotonic() > deadline:
            raise RuntimeError(f"the vehicle did not {what} within {timeout_s:g} s")
        time.sleep(0.05)


def mavsdk_log(level: LogLevel, message: str, _file: str | None, _line: int) -> bool:
    """MAVSDK's own log: its warnings and errors on stderr, its info and debug lines not at all."""
    if level in (LogLevel.WARN, LogLevel.ERROR):
        print(f"MAVSDK: {message}", file=sys.stderr)
    return True                               # handled: MAVSDK prints nothing itself


def main() -> int:
    log_subscribe(mavsdk_log)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:      # a free UDP port for the ground station
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    drone = Mavsdk(config)
    vehicle = None
    try:
        # Listen first, then start the vehicle: it sends its heartbeat and telemetry to this port.
        if drone.add_any_connection(f"udpin://127.0.0.1:{port}") != ConnectionResult.SUCCESS:
            raise RuntimeError(f"MAVSDK cannot listen on UDP port {port}")
        vehicle = Vehicle(VehicleConfig(url=f"udpout:127.0.0.1:{port}", time_scale=10.0)).start()
        system = drone.first_autopilot(10.0)
        if system is None:
            raise RuntimeError("no autopilot answered within 10 s")
        action, telemetry = Action(system), Telemetry(system)
        wait_for("send its home position", lambda: math.isfinite(telemetry.home().latitude_deg), 10)
        home = telemetry.home()
        print(f"connected: autopilot {system.get_system_id()} ({system.autopilot_type().name}), home "
              f"{home.latitude_deg:.6f} {home.longitude_deg:.6f} at {home.absolute_altitude_m:.1f} m")

        def where() -> tuple[float, float, float]:      # (north, east, altitude above home) from telemetry
            p = telemetry.position()
            north, east = geo_to_ned(p.latitude_deg, p.longitude_deg, home.latitude_deg, home.longitude_deg)
            return north, east, p.relative_altitude_m

        action.arm()                          # each action waits for the vehicle's COMMAND_ACK (ActionError if refused)
        wait_for("arm", telemetry.armed, 5)
        print("armed")
        action.set_takeoff_altitude(ALTITUDE_M)
        action.takeoff()
        wait_for(f"climb to {ALTITUDE_M:g} m", lambda: abs(where()[2] - ALTITUDE_M) < 0.3, 30)
        print(f"took off: {where()[2]:.1f} m above home, in the air: {telemetry.in_air()}")

        lat, lon = ned_to_geo(NORTH_M, EAST_M, home.latitude_deg, home.longitude_deg)
        action.goto_location(lat, lon, home.absolute_altitude_m + ALTITUDE_M, 0.0)   # yaw 0: face north
        wait_for("reach its goto target",
                 lambda: math.dist(where(), (NORTH_M, EAST_M, ALTITUDE_M)) < 0.5, 30)
        north, east, alt = where()
        print(f"flew to N {north:.1f} E {east:.1f} m at {alt:.1f} m (asked N {NORTH_M:g} E {EAST_M:g})")

        action.land()
        wait_for("land and disarm", lambda: telemetry.landed_state() == LandedState.ON_GROUND
                 and not telemetry.armed(), 60)
        n, e, d, _yaw = vehicle.pose()          # the simulator's own truth, beside what MAVLink reported
        print(f"landed and disarmed: the simulator has it on the ground at N {n:.1f} E {e:.1f} "
              f"(altitude {max(0.0, -d):.1f} m) after {vehicle.sim_time_s:.0f} s of simulated flight, "
              f"battery {100 * vehicle.battery_remaining:.1f} %")
        return 0
    finally:
        if vehicle is not None:
            vehicle.stop()                    # its threads and its socket
        drone.destroy()                       # MAVSDK's threads and sockets
        config.destroy()


if __name__ == "__main__":
    try:
        sys.exit(main())
    except Exception as exc:                  # MAVSDK's ActionError, a timeout: one line, exit 1
        sys.exit(f"fly_vehicle_mavsdk: {type(exc).__name__}: {exc}")
