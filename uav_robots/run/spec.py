"""`uav-robots run`'s arguments as one RunSpec (protocol/run_spec.py): built once the arguments are
checked, written to OUT/run.json for every process the run starts; `run --spec FILE` starts from one."""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from protocol.run_spec import (RUN_JSON, CameraSpec, HostingSpec, LimitsSpec, PlanningSpec, RunSpec, VehicleSpec,
                               apply_spec)

# Every flag of `run` a spec gives, when the command line does not.
RUN_FIELDS = {
    "--map": lambda s: s.map, "--robots": lambda s: s.robots, "--seed": lambda s: s.seed, "--scen": lambda s: s.scen,
    "--camera": lambda s: s.camera.model, "--camera-source": lambda s: s.camera.source,
    "--scene": lambda s: s.scene.text(), "--wobble": lambda s: s.vehicle.wobble_deg,
    "--vehicle-preset": lambda s: s.vehicle.preset, "--time-scale": lambda s: s.vehicle.time_scale,
    "--autopilot": lambda s: s.vehicle.autopilot, "--autopilot-pose": lambda s: s.vehicle.autopilot_pose,
    "--autopilot-origin": lambda s: s.vehicle.autopilot_origin, "--gcs": lambda s: s.vehicle.gcs,
    "--mavlink-key": lambda s: s.vehicle.mavlink_key, "--mavlink-bind": lambda s: s.vehicle.mavlink_bind,
    "--fault": lambda s: list(s.faults),
    "--planner": lambda s: s.planning.planner, "--assign": lambda s: s.planning.assign,
    "--connectivity": lambda s: s.planning.connectivity, "--time-limit": lambda s: s.planning.time_limit_s,
    "--no-fallback": lambda s: not s.planning.fallback,
    "--tick-timeout": lambda s: s.limits.tick_timeout_s, "--tick-rate": lambda s: s.limits.tick_rate_hz,
    "--monitor-every": lambda s: s.limits.monitor_every, "--look-every": lambda s: s.limits.look_every,
    "--timeout": lambda s: s.limits.timeout_s,
    "--robots-per-process": lambda s: s.hosting.robots_per_process, "--secure": lambda s: s.hosting.secure,
}


def from_spec_file(args: argparse.Namespace) -> None:
    """`run --spec FILE`: the spec's values for every flag not given (before the checks, which see them all)."""
    apply_spec(args, RUN_FIELDS)


def _whole(path: str | None) -> str | None:
    """A file or directory the spec names, whole: a run repeated from elsewhere finds it."""
    return str(Path(path).resolve()) if path and Path(path).exists() else path


def spec_of(args: argparse.Namespace) -> RunSpec:
    """The checked arguments as a spec (resolved: the time scale, 10 for our vehicle and 1 for another
    autopilot; the scene and the wobble the camera preset's when not given; the files it names whole)."""
    from scenarios.scene import scene_of_args
    from sim_world.camera.model import camera_preset
    from sim_world.vehicle.config import WOBBLE_OF_CAMERA_PRESET

    preset = camera_preset(args.camera)
    wobble = args.wobble if args.wobble is not None else WOBBLE_OF_CAMERA_PRESET[preset]
    scene = scene_of_args(args, preset)
    return RunSpec(
        map=_whole(args.map), robots=args.robots, seed=args.seed, scen=_whole(args.scen),
        camera=CameraSpec(source=args.camera_source, model=args.camera),
        scene=dataclasses.replace(scene, routes=_whole(scene.routes)),
        vehicle=VehicleSpec(preset=args.vehicle_preset, time_scale=float(args.time_scale),
                            wobble_deg=float(wobble), autopilot=args.autopilot,
                            autopilot_pose=args.autopilot_pose, autopilot_origin=args.autopilot_origin, gcs=args.gcs,
                            mavlink_key=_whole(args.mavlink_key), mavlink_bind=args.mavlink_bind),
        faults=tuple(f.strip() for f in args.fault),
        planning=PlanningSpec(planner=args.planner, assign=args.assign, connectivity=args.connectivity,
                              time_limit_s=float(args.time_limit), fallback=not args.no_fallback),
        limits=LimitsSpec(tick_timeout_s=float(args.tick_timeout), tick_rate_hz=float(args.tick_rate),
                          monitor_every=args.monitor_every,
                          look_every=args.look_every, timeout_s=float(args.timeout)),
        hosting=HostingSpec(robots_per_process=args.robots_per_process, secure=_whole(args.secure)))


def write_spec(out: Path, spec: RunSpec) -> Path:
    from ..common.outputs import write_atomic

    path = out / RUN_JSON
    write_atomic(path, spec.to_json())
    return path
