"""`uav-robots vehicle`: the simulated autopilot alone, a process of its own, as a SITL binary is.

    uav-robots vehicle --mavlink udpout:127.0.0.1:14540 --gcs udpout:127.0.0.1:14550
    python -m sim_world.vehicle ...                        # the same

`--mavlink` is the companion's link (the UAV agent's: PX4 SITL's API port 14540), `--gcs` a ground
station's (QGroundControl's 14550), `--pose-link` a third one for a reader of the pose (the world
follows the vehicle there: `uav-robots world --autopilot-pose URL`). It runs until SIGTERM or
Ctrl-C; what it does (armed, took off, landed, a crash, every STATUSTEXT) is its log, one line each.

The options every vehicle takes are defined here, and `uav-robots world` (which flies a vehicle in
its own process unless it follows one) takes the same.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any

from protocol.errors import MissionError, UavRobotsError
from protocol.faults import CATALOGUE, VEHICLE, parse_fault, usage
from protocol.run_spec import add_spec_argument, apply_spec

DEFAULT_URL = "udpout:127.0.0.1:14540"
LOG_EVERY_S = 0.2
# Told to stop in the air, the vehicle lands first for at most this long (wall seconds): from 120 m at
# PX4's land speeds and time scale 1 a landing takes about a minute; a launcher waits longer (VEHICLE_STOP_S).
LAND_ON_STOP_S = 90.0


def add_ground_station_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--gcs", default=None, metavar="URL",
                   help="a second MAVLink link to the vehicle for a ground station, e.g. udpout:127.0.0.1:14550 "
                        "(QGroundControl's port) or udpin:127.0.0.1:14551")
    p.add_argument("--mavlink-key", default=None, metavar="FILE",
                   help="sign the --gcs link with this MAVLink 2 key (32 raw bytes or 64 hex digits); "
                        "unsigned frames are refused there")
    p.add_argument("--mavlink-bind", default="127.0.0.1", metavar="HOST",
                   help="address the vehicle's MAVLink sockets are bound to (default 127.0.0.1: only this "
                        "machine can reach it; 0.0.0.0 opens it to the network)")


def parse_home(text: str | None) -> tuple[float, float, float] | None:
    """`--home LAT,LON,ALT`, or None when not given; one line for a bad one."""
    if not text:
        return None
    try:
        home = tuple(float(v) for v in text.split(","))
    except ValueError:
        home = ()
    if len(home) != 3 or not all(map(math.isfinite, home)):
        raise UavRobotsError(f"--home {text!r} is not LAT,LON,ALT")
    return home  # type: ignore[return-value]


def parse_params(specs: list[str]) -> dict[str, float]:
    """`--param NAME=VALUE`, as PX4 SITL's `param set`; the names are checked against the vehicle's."""
    params = {}
    for spec in specs:
        name, eq, value = spec.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not (eq and name.strip() and math.isfinite(number)):
            raise UavRobotsError(f"--param {spec!r}: give NAME=VALUE, e.g. GF_MAX_HOR_DIST=1500")
        params[name.strip().upper()] = number
    return params


def add_vehicle_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("vehicle", help="run the simulated autopilot alone (a PX4-like SITL over MAVLink)",
                              description="Fly the simulated PX4-like multicopter over MAVLink, as a SITL binary: "
                                          "the UAV agent on --mavlink, a ground station on --gcs, the world's "
                                          "camera on --pose-link.")
    add_vehicle_arguments(p)
    p.set_defaults(func=vehicle_command)
    return p


def add_vehicle_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mavlink", default=DEFAULT_URL, metavar="URL",
                   help=f"the companion's MAVLink link, pymavlink's spelling (default {DEFAULT_URL}, where the UAV "
                        "agent listens as MAVSDK does for PX4 SITL)")
    add_ground_station_arguments(p)
    p.add_argument("--pose-link", default=None, metavar="URL",
                   help="a third link, unsigned, for a reader of the pose: `uav-robots world --autopilot-pose` "
                        "renders its camera from the telemetry there (e.g. udpout:127.0.0.1:14580)")
    p.add_argument("--home", default=None, metavar="LAT,LON,ALT",
                   help="home, where the vehicle stands at start (default PX4 SITL's, near Zurich); the world "
                        "puts the floor's top-left corner there")
    p.add_argument("--time-scale", type=float, default=1.0, metavar="X", help="simulated seconds per second")
    p.add_argument("--seed", type=int, default=0, help="seed of the hover wobble")
    p.add_argument("--heading", type=float, default=None, metavar="DEG",
                   help="where the vehicle faces when it boots, degrees from north (default 0)")
    p.add_argument("--wobble", type=float, default=0.0, metavar="DEG",
                   help="amplitude of the roll and pitch wobble in a hover, degrees (default 0)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="set a parameter at start (repeatable), e.g. GF_MAX_HOR_DIST=1500")
    p.add_argument("--preset", default="outdoor", choices=("outdoor", "indoor"),
                   help="outdoor (GPS, a home; default) or indoor (no GPS: a local frame only, no home, as PX4 "
                        "flying on vision or optical flow)")
    p.add_argument("--position-noise", type=float, default=0.0, metavar="M",
                   help="white noise (1 sigma, m) on the reported position (default 0: telemetry is the truth)")
    p.add_argument("--position-bias", type=float, default=0.0, metavar="M",
                   help="the estimate's slowly wandering error (1 sigma, m): the vehicle holds where it believes "
                        "it is, off by it (default 0)")
    p.add_argument("--attitude-noise", type=float, default=0.0, metavar="DEG",
                   help="white noise (1 sigma, degrees) on the reported roll, pitch and yaw (default 0)")
    p.add_argument("--streams-until-asked", action="store_true", default=None,
                   help="send nothing but the heartbeat until a link asks for a stream (SET_MESSAGE_INTERVAL), as "
                        "ArduPilot does with its SRn_ rates at 0")
    p.add_argument("--ready-after", type=float, default=None, metavar="S",
                   help="refuse arming for this many simulated seconds after boot (an estimator settling; "
                        "ArduPilot SITL accepts GUIDED and arming only about 38 s after it starts)")
    p.add_argument("--companion", type=int, default=None, metavar="SYSID",
                   help="the only MAVLink system the flight link answers (default: the first that talks to it)")
    p.add_argument("--fault", action="append", default=[], metavar=usage(VEHICLE),
                   help="inject a fault into the vehicle (repeatable): " + "; ".join(
                       f"{k.form}: {k.help}" for k in CATALOGUE if k.injector == VEHICLE))
    add_spec_argument(p)


# What the vehicle takes from a run's spec (`--spec OUT/run.json`).
SPEC_FIELDS = {
    "--time-scale": lambda s: s.vehicle.time_scale, "--seed": lambda s: s.seed, "--preset": lambda s: s.vehicle.preset,
    "--gcs": lambda s: s.vehicle.gcs, "--mavlink-key": lambda s: s.vehicle.mavlink_key,
    "--mavlink-bind": lambda s: s.vehicle.mavlink_bind, "--wobble": lambda s: s.vehicle.wobble_deg,
    "--fault": lambda s: s.faults_for(VEHICLE),
}


def vehicle_config_from_args(args: argparse.Namespace) -> Any:
    """The VehicleConfig the arguments give: links, bind address, signing key, home; one-line errors."""
    from .vehicle.config import preset, read_signing_key

    if args.mavlink_key and not args.gcs:
        raise UavRobotsError("--mavlink-key signs the ground-station link: give --gcs URL too")
    home = parse_home(args.home)
    where = {} if home is None else {"home_lat": home[0], "home_lon": home[1], "home_alt_m": home[2]}
    try:  # bad input, not a failed mission: exit 2
        key = read_signing_key(args.mavlink_key) if args.mavlink_key else None
        return preset(getattr(args, "preset", "outdoor"), url=args.mavlink, gcs_url=args.gcs, signing_key=key,
                      pose_url=args.pose_link, bind_host=args.mavlink_bind, time_scale=args.time_scale,
                      seed=args.seed, hover_wobble_deg=args.wobble, **where, **_estimate_options(args))
    except MissionError as exc:
        raise UavRobotsError(str(exc)) from None


def _estimate_options(args: argparse.Namespace) -> dict:
    """The vehicle-only options (`uav-robots world`, which shares the rest, has none of these)."""
    names = {"heading": "heading_deg", "position_noise": "position_noise_m", "position_bias": "position_bias_m",
             "attitude_noise": "attitude_noise_deg", "companion": "companion_system_id",
             "streams_until_asked": "streams_until_asked", "ready_after": "ready_after_s"}
    options = {field: getattr(args, arg) for arg, field in names.items() if getattr(args, arg, None) is not None}
    for f in (parse_fault(spec, VEHICLE) for spec in getattr(args, "fault", [])):
        if f.kind == "battery":
            options["battery_drop"] = (f.pct / 100.0, float(f.seconds))
        elif f.kind == "mavlink":
            options["link_loss"] = (float(f.seconds), float(f.duration))
    return options


def vehicle_command(args: argparse.Namespace) -> int:
    from protocol.process import Lifecycle

    from .vehicle import Vehicle

    apply_spec(args, SPEC_FIELDS)
    cfg = vehicle_config_from_args(args)
    params = parse_params(args.param)
    vehicle = Vehicle(cfg)
    for name, value in params.items():
        try:
            vehicle.param(name)
        except KeyError:
            raise UavRobotsError(f"--param {name}: the vehicle has no such parameter") from None
        vehicle.set_param(name, value)
    vehicle.start()
    links = [f"mavlink {cfg.url}"] + [f"{what} {url}" for what, url in (("ground station", cfg.gcs_url),
                                                                          ("pose", cfg.pose_url)) if url]
    where = (f"home {cfg.home_lat:.7f} {cfg.home_lon:.7f} {cfg.home_alt_m:.1f} m" if cfg.gps
             else "indoor: no GPS, a local frame only")
    print(f"vehicle ready: {', '.join(links)}; {where}, time scale {cfg.time_scale:g}" + (" (ground station signed)" if cfg.signing_key else ""), flush=True)
    life = Lifecycle()
    life.stop_on_signals()   # SIGTERM or Ctrl-C: a clean stop, exit 0, as the world's
    told = [0]
    try:
        life.serve(LOG_EVERY_S, lambda: _log_events(vehicle, told))
        _land_before_stopping(vehicle, lambda: _log_events(vehicle, told))
    finally:
        vehicle.stop()
        _log_events(vehicle, told)
        print(f"vehicle: stopped; armed {vehicle.armed}, {vehicle.landed_state.name}, highest "
              f"{vehicle.max_altitude_m:.1f} m, {vehicle.bad_frames} bad frame(s), {vehicle.refused_unsigned} "
              "refused unsigned", flush=True)
    return 0


def _land_before_stopping(vehicle: Any, log: Any) -> None:
    """Told to stop in the air (the UAV died, `run` ends): land first, as the datalink failsafe would,
    rather than leave a simulated drone that vanishes mid-air; bounded by LAND_ON_STOP_S."""
    if not (vehicle.armed and vehicle.in_air):
        return
    print("vehicle: told to stop in the air: landing first", flush=True)
    vehicle.land_now("stopped in the air")
    deadline = time.monotonic() + LAND_ON_STOP_S
    while vehicle.armed and time.monotonic() < deadline:
        time.sleep(LOG_EVERY_S)
        log()


def _log_events(vehicle: Any, told: list[int]) -> None:
    """The events since the last call, one line each, stamped with simulated seconds."""
    events = vehicle.events
    for t, text in events[told[0]:]:
        print(f"[{t:9.2f}] {text}", flush=True)
    told[0] = len(events)


def main(argv: list[str] | None = None) -> int:
    from protocol.process import command_main, one_command

    return command_main(one_command("python -m sim_world.vehicle", "The simulated PX4-like autopilot alone.",
                                    add_vehicle_arguments, vehicle_command), argv)


if __name__ == "__main__":
    sys.exit(main())
