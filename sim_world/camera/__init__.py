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

What is on the floor (render.Scene), in cell units (a cell is 1 x 1):
- floor light grey (215), shelves dark brown, outside the grid dark blue;
- surveyed landmarks (scenarios.landmarks, `landmark_spacing` > 0): DICT_5X5_1000
  markers, black square 0.75 of a 2x2 (or 1x1) block of shelf cells, white quiet
  zone filling the rest of the block, top edge north;
- `goal_pads` 0 (ideal, today's layout): a goal is a green disc of radius 0.345
  with a dark ring to 0.415; a robot is a white full cell carrying its
  DICT_4X4_1000 marker of 0.75 cell (module 1/8 cell), which hides a goal under it;
- `goal_pads` 1 (realistic): a goal is a green square pad of 0.96 cell centred in
  its cell; a robot is a white square body of 0.8 cell centred in its cell, its
  marker (6 modules: 4x4 data + black border) 6/7 of the body = 0.686 cell
  (module 0.8/7 = 0.114 cell) centred with half a module of white around it; a
  robot on a goal therefore shows a green frame 0.08 cell wide around its body.

Modules: model (keys, presets), render (geometry, texture, lens), degrade
(blur, lighting, vignetting, noise), encode (PNG/JPEG, the message), estimate
(the pose error), capture (one exposure: all of them).
"""
from .capture import VehicleView, calibration_frame, capture_frame, prepare
from .degrade import motion_kernel
from .encode import camera_frame, encode_frame, encode_image
from .estimate import PoseEstimator
from .model import (DEFAULT_CAMERA_PRESET, KEYS, PRESETS, CameraModel, camera_model_from, camera_options)
from .render import (ARUCO_DICTIONARY, MARKER_IDS, CameraPose, Roi, Scene, camera_rotation, cell_centre_ned,
                     clip_roi, floor_homography, render, scene_landmarks)

__all__ = ["ARUCO_DICTIONARY", "CameraModel", "CameraPose", "DEFAULT_CAMERA_PRESET", "KEYS", "MARKER_IDS", "PRESETS",
           "PoseEstimator", "Roi", "Scene", "VehicleView", "calibration_frame", "camera_frame", "camera_model_from", "camera_options",
           "camera_rotation", "capture_frame", "cell_centre_ned", "clip_roi", "encode_frame", "encode_image", "floor_homography",
           "motion_kernel", "prepare", "render", "scene_landmarks"]
