"""One exposure: the image rendered from the vehicle's TRUE pose and motion, published with
the vehicle's ESTIMATE of its pose."""
from __future__ import annotations

from typing import NamedTuple

from protocol.messages import CameraFrame

from .encode import encode_frame
from .estimate import PoseEstimator
from .model import CameraModel
from .render import CameraPose, Scene, render


class VehicleView(NamedTuple):
    """The camera's true pose at exposure, and the vehicle's velocity (NED, m/s)."""
    north_m: float
    east_m: float
    down_m: float
    yaw_rad: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    vel_north: float = 0.0
    vel_east: float = 0.0
    vel_down: float = 0.0

    @property
    def pose(self) -> CameraPose:
        return CameraPose(*self[:6])


def capture_frame(scene: Scene, view: VehicleView, model: CameraModel, cell_size_m: float,
                  estimator: PoseEstimator, time_s: float, seq: int = 0, seed: int | None = None) -> CameraFrame:
    image = render(scene, view.pose, model, cell_size_m, seed=seed if seed is not None else seq,
                   velocity_ned=(view.vel_north, view.vel_east, view.vel_down))
    return encode_frame(image, estimator.estimate(view.pose, time_s), model, time_s, seq)
