"""One exposure: the image rendered from the vehicle's TRUE pose and motion, published with
the vehicle's ESTIMATE of its pose."""
from __future__ import annotations

from collections.abc import Callable


from protocol.messages import CameraFrame

from .degrade import prepare_degrade
from ..pose_track import Pose
from .encode import camera_frame, encode_frame
from .estimate import PoseEstimator
from .model import CameraModel
from .render import CameraPose, Roi, Scene, lens_for, render


class VehicleView(Pose):
    """The camera's true pose at exposure, and the vehicle's velocity (NED, m/s)."""
    __slots__ = ()

    @property
    def pose(self) -> CameraPose:
        return CameraPose(*self[:6])


def _camera_pose(view: VehicleView, model: CameraModel) -> CameraPose:
    pose = view.pose
    if model.gimbal:   # a stabilised camera stays level whatever the airframe does
        pose = pose._replace(roll_rad=0.0, pitch_rad=0.0)
    return pose


def calibration_frame(view: VehicleView, model: CameraModel, estimator: PoseEstimator, time_s: float,
                      seq: int = 0) -> CameraFrame:
    """What a `calibration_only` request gets: the frame of an exposure now, without its image."""
    return camera_frame(estimator.estimate(_camera_pose(view, model), time_s), model, time_s, b"", seq,
                        "jpeg" if model.jpeg_quality else "png")


def capture_frame(scene: Scene, view: VehicleView, model: CameraModel, cell_size_m: float,
                  estimator: PoseEstimator, time_s: float, seq: int = 0, seed: int | None = None,
                  roi: Roi | None = None) -> CameraFrame:
    """An exposure from `view`: the whole image, or the sensor's region `roi` (see render)."""
    pose = _camera_pose(view, model)
    image = render(scene, pose, model, cell_size_m, seed=seed if seed is not None else seq,
                   velocity_ned=(view.vel_north, view.vel_east, view.vel_down), roi=roi)
    return encode_frame(image, estimator.estimate(pose, time_s), model, time_s, seq, roi)


def view_image(scene: Scene, view: VehicleView, model: CameraModel, cell_size_m: float, seed: int = 0):
    """The BGR image of an exposure from `view`, not encoded (a video frame)."""
    return render(scene, _camera_pose(view, model), model, cell_size_m, seed=seed,
                  velocity_ned=(view.vel_north, view.vel_east, view.vel_down))


def prepare(model: CameraModel, stopped: Callable[[], bool] = lambda: False) -> None:
    """Build the model's cached tables (the lens's distortion map, the gain field, the noise
    bank: about 1 s at 12 MP) ahead of the first exposure, which would otherwise pay for them;
    given up, unbuilt, soon after `stopped()` turns true."""
    lens_for(model)
    prepare_degrade(model, stopped)
