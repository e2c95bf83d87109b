"""The world's configuration: what one world process simulates and serves, checked before it starts."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from protocol.errors import MissionError, UavRobotsError
from protocol.keys import Keys
from protocol.run_spec import SceneSpec
from scenarios.limits import check_fleet

# PX4 SITL's default home: a field near Zurich. The grid's top-left corner is there.
HOME = (47.397742, 8.545594, 488.0)
MOVE_BATCH_TIMEOUT_S = 2.0
# A 12 MP camera, as on common survey drones: it covers the 450x450 warehouse in 12
# images at 20 px per cell where a 1280x960 one needs 80 (and 80 flights between them).
DRONE_CAMERA = {"width": 4000, "height": 3000}


@dataclass
class WorldConfig:
    fleet: str
    map: str = "warehouse-small"
    robots: int = 8
    seed: int = 0
    scen: str | None = None           # a MovingAI .scen: starts and goals from its first `robots` lines
    connectivity: int = 4
    cell_size_m: float = 1.0
    home_lat: float = HOME[0]
    home_lon: float = HOME[1]
    home_alt_m: float = HOME[2]
    mavlink: str | None = "udpout:127.0.0.1:14540"   # None: no vehicle (tests of the services alone)
    gcs: str | None = None            # a second MAVLink link, for a ground station
    mavlink_key: str | None = None    # a file with the MAVLink 2 signing key of the gcs link
    mavlink_bind: str = "127.0.0.1"   # the address the vehicle's sockets are bound to
    # Follow an autopilot the world does not fly (sim_world/pose_follower.py): its pose link, and where
    # its local origin lies on the floor (None: its first home is the floor's corner).
    autopilot_pose: str | None = None
    autopilot_origin: tuple[float, float, float] | None = None
    time_scale: float = 1.0
    camera: dict[str, Any] = field(default_factory=dict)  # sim_world.camera.CameraModel fields
    # The floor's marks (scenarios/scene.py); by default the plain floor of the default (ideal) camera.
    scene: SceneSpec = field(default_factory=lambda: SceneSpec(landmark_spacing=0, goal_pads=False))
    wobble_deg: float = 0.0           # its vehicle's hover wobble (amplitude)
    camera_height_m: float = 0.3      # lens above the floor when the vehicle sits on it
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    zenoh_config: str | None = None
    move_batch_timeout_s: float = MOVE_BATCH_TIMEOUT_S
    slip: float = 0.0                 # probability that a move ends elsewhere, unknown to the robot
    skids: dict[int, int] = field(default_factory=dict)   # robot -> tick from which all its moves end elsewhere
    end_timeout_s: float = 120.0      # after MissionEnd, the longest wait for the UAV to leave
    camera_mavlink: str | None = None  # the camera's own MAVLink link (camera/mavlink_camera.py); None: none
    camera_video: str | None = None    # udp://HOST:PORT: its H.264 RTP stream (camera/stream.py); None: none

    def check(self) -> None:
        Keys(self.fleet)
        check_fleet(self.robots)
        if self.connectivity not in (4, 8):
            raise UavRobotsError(f"connectivity must be 4 or 8, got {self.connectivity}")
        if not self.cell_size_m > 0:
            raise UavRobotsError(f"cell size must be positive, got {self.cell_size_m}")
        if not self.move_batch_timeout_s > 0:
            raise UavRobotsError(f"the move batch timeout must be positive, got {self.move_batch_timeout_s}")
        if not self.time_scale > 0:
            raise UavRobotsError(f"time scale must be positive, got {self.time_scale}")
        if self.connect and self.listen:
            raise UavRobotsError("give --connect or --listen, not both")
        if self.autopilot_pose:
            from .pose_follower import check_pose_url
            if self.gcs or self.mavlink_key:   # its `mavlink` is not opened
                raise UavRobotsError("with --autopilot-pose the world runs no vehicle: give --gcs and --mavlink-key "
                                     "to the autopilot (`uav-robots vehicle`)")
            check_pose_url(self.autopilot_pose, self.mavlink_bind)
        elif self.mavlink:
            vehicle_config(self)
        elif self.gcs or self.mavlink_key:
            raise UavRobotsError("--gcs and --mavlink-key need a vehicle (--mavlink is none)")


def vehicle_config(cfg: WorldConfig) -> Any:
    """The vehicle's configuration, checked (links, bind address, signing key): one-line errors."""
    from .vehicle.config import VehicleConfig, read_signing_key

    if cfg.mavlink_key and not cfg.gcs:
        raise UavRobotsError("--mavlink-key signs the ground-station link: give --gcs URL too")
    try:  # bad input, not a failed mission: exit 2
        key = read_signing_key(cfg.mavlink_key) if cfg.mavlink_key else None
        return VehicleConfig(url=cfg.mavlink or "udpout:127.0.0.1:14540", home_lat=cfg.home_lat,
                             home_lon=cfg.home_lon, home_alt_m=cfg.home_alt_m, time_scale=cfg.time_scale,
                             gcs_url=cfg.gcs, signing_key=key, bind_host=cfg.mavlink_bind,
                             hover_wobble_deg=cfg.wobble_deg, seed=cfg.seed)
    except MissionError as exc:
        raise UavRobotsError(str(exc)) from None


def fence_reach_m(shape: tuple[int, ...], cell_size_m: float) -> float:
    """The geofence radius that keeps a floor of `shape` cells inside: its farthest corner, with a margin."""
    h, w = shape[:2]
    return 1.2 * math.hypot(h, w) * cell_size_m + 10.0
