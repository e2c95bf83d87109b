"""The published frame: the image (lossless PNG, or JPEG as a real video link sends it) with
the intrinsics, the lens's distortion, and the vehicle's pose ESTIMATE with its stated sigmas."""
from __future__ import annotations

import cv2
import numpy as np

from protocol.errors import MissionError
from protocol.messages import CameraFrame

from .model import CameraModel
from .render import CameraPose, Roi, as_pose


def camera_frame(pose: CameraPose | tuple, model: CameraModel, time_s: float, png: bytes = b"",
                 seq: int = 0, encoding: str = "png", roi: Roi | None = None) -> CameraFrame:
    """The CameraFrame message for a (published) pose and the model, carrying `png` (the image
    bytes, in `encoding`). Roll and pitch come from the pose; the sigmas from the model. A
    region `roi` of the sensor is a camera of its size whose principal point is shifted by its
    corner (the lens's distortion is relative to the principal point, so it stays as it is)."""
    p = as_pose(pose)
    x0, y0, w, h = roi if roi is not None else (0, 0, model.width, model.height)
    return CameraFrame(width=w, height=h, fx=model.fx, fy=model.fy, cx=model.cx - x0,
                       cy=model.cy - y0, north_m=p.north_m, east_m=p.east_m, down_m=p.down_m, yaw_rad=p.yaw_rad,
                       time_s=float(time_s), png=png, seq=seq, k1=model.k1, k2=model.k2, p1=model.p1,
                       p2=model.p2, k3=model.k3, roll_rad=p.roll_rad, pitch_rad=p.pitch_rad,
                       pose_sigma_m=model.pose_sigma_m, yaw_sigma_deg=model.yaw_sigma_deg, encoding=encoding)


def encode_image(image: np.ndarray, model: CameraModel, roi: Roi | None = None) -> tuple[bytes, str]:
    """(bytes, encoding): JPEG at `model.jpeg_quality`, or PNG (fast, lossless) when it is 0."""
    w, h = (roi.width, roi.height) if roi is not None else (model.width, model.height)
    if image.shape[:2] != (h, w):
        raise MissionError(f"camera: image is {image.shape[1]}x{image.shape[0]}, model says {w}x{h}")
    if model.jpeg_quality:
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, model.jpeg_quality])
        encoding = "jpeg"
    else:
        ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        encoding = "png"
    if not ok:  # pragma: no cover - OpenCV refuses only malformed arrays
        raise MissionError(f"camera: {encoding} encoding failed")
    return buf.tobytes(), encoding


def encode_frame(image: np.ndarray, pose: CameraPose | tuple, model: CameraModel, time_s: float,
                 seq: int = 0, roi: Roi | None = None) -> CameraFrame:
    """Image (of the sensor's region `roi`, if given) + published pose + model -> the CameraFrame message."""
    data, encoding = encode_image(image, model, roi)
    return camera_frame(pose, model, time_s, data, seq, encoding, roi)
