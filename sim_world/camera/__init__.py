"""The vehicle's nadir camera: renders what it sees of the warehouse floor.

Frames (shared with `uav_agent.perception`, which re-derives the same geometry
from the published `CameraFrame` fields only):
- local NED, origin at the grid's top-left corner: north = -y, east = +x;
  cell (x, y) spans east [x*c, (x+1)*c] and north [-(y+1)*c, -y*c];
- the camera is fixed to the body looking down (nadir when level) and turns with
  the vehicle: at yaw, pitch and roll 0 image "up" points north and image "right"
  points east; NED -> camera is R = C @ (Rz(yaw) Ry(pitch) Rx(roll))^T with
  C = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]] (render.camera_rotation);
- pinhole intrinsics fx, fy, cx, cy in OpenCV's pixel-centre convention, then
  Brown-Conrady distortion (k1, k2, p1, p2, k3) exactly as OpenCV models it;
- the pose published in a CameraFrame is the vehicle's ESTIMATE (estimate.py),
  the image is rendered from the truth.

Modules: model (keys, presets), render (geometry, texture, lens), degrade
(blur, lighting, vignetting, noise), encode (PNG/JPEG, the message), estimate
(the pose error), capture (one exposure: all of them).
"""
from .capture import VehicleView, capture_frame
from .degrade import motion_kernel
from .encode import camera_frame, encode_frame, encode_image
from .estimate import PoseEstimator
from .model import (DEFAULT_CAMERA_PRESET, KEYS, PRESETS, CameraModel, camera_model_from, camera_options)
from .render import (ARUCO_DICTIONARY, MARKER_IDS, CameraPose, Scene, camera_rotation, cell_centre_ned,
                     floor_homography, render, scene_landmarks)

__all__ = ["ARUCO_DICTIONARY", "CameraModel", "CameraPose", "DEFAULT_CAMERA_PRESET", "KEYS", "MARKER_IDS", "PRESETS",
           "PoseEstimator", "Scene", "VehicleView", "camera_frame", "camera_model_from", "camera_options",
           "camera_rotation", "capture_frame", "cell_centre_ned", "encode_frame", "encode_image", "floor_homography",
           "motion_kernel", "render", "scene_landmarks"]
