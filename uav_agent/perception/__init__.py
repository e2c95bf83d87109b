"""Camera frames -> world model: occupancy grid, robots by marker id, goal cells.

Uses only the images, their `CameraFrame` metadata (intrinsics, calibration,
the vehicle's pose estimate) and the world's published map facts (grid size,
surveyed landmarks): never the world's ground truth. One module per job:
`frames` (decode, undistort), `registration` (where the image was taken, from
landmarks), `occupancy` (floor or shelf, adaptive), `markers` (robots),
`goals` (green pads), `fusion` (all views into one model, by confidence).
"""
from .frames import Frame, decode_frame
from .fusion import FrameReport, Fusion, WorldModel, perceive
from .registration import Landmarks, Registration, homography, register

__all__ = ["Frame", "FrameReport", "Fusion", "Landmarks", "Registration", "WorldModel", "decode_frame", "homography",
           "perceive", "register"]
