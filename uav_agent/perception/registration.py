"""Where each image was taken, from the image itself: surveyed floor fiducials.

The pose in a `CameraFrame` is the vehicle's estimate, off by its stated sigma
(tens of centimetres, a degree or more of yaw): far too much to place cells and
markers. The world's surveyed landmarks (ArUco markers at known floor
positions, `WorldInfo.landmarks`) give each image its own registration:
detect them in the undistorted image, name each detection's instance by the
nearest surveyed marker with that id to where the pose estimate predicts it
(ids repeat only with a period far beyond any pose error), reject outliers with
a RANSAC homography, then solve the camera pose (solvePnP, IPPE: the points are
coplanar) and derive the floor homography from it. Roll and pitch come out of
the solve, so a tilted camera is handled like a level one.

Too few landmarks in view: the estimate (with its stated sigma) is all there is,
and the frame is marked as such so that fusion trusts its cells less.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from protocol.errors import MissionError, ProtocolError
from protocol.grid import Cell
from protocol.messages import CameraFrame, WorldInfo

from .frames import intrinsics

MIN_LANDMARKS = 2          # one small marker pins the position, not the tilt
RANSAC_PX = 3.0            # homography inlier threshold
MAX_REPROJECTION_PX = 2.5  # an accepted registration's RMS error over its inliers
QUIET_ZONE = 1 / 0.75      # a landmark's white block, as a multiple of its black square's side

# Camera axes (columns) in the vehicle's body frame (x forward, y right, z down):
# a nadir camera whose image right is the body's right and image up its nose.
_CAMERA_IN_BODY = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class Landmarks:
    """The surveyed fiducials: family (OpenCV ArUco dictionary), black-square side, centres by id."""
    family: str
    size_m: float
    by_id: dict[int, np.ndarray]    # id -> (k, 2) array of (east_m, north_m), k >= 1

    @classmethod
    def from_info(cls, info: WorldInfo) -> Landmarks | None:
        family = getattr(info, "landmark_family", "")
        marks = getattr(info, "landmarks", [])
        if not family or not marks or not getattr(info, "landmark_size_m", 0.0) > 0:
            return None
        if not hasattr(cv2.aruco, family):
            raise MissionError(f"world info: landmark family {family!r} is not an OpenCV ArUco dictionary")
        by_id: dict[int, list[tuple[float, float]]] = {}
        for rid, east, north in marks:
            by_id.setdefault(int(rid), []).append((float(east), float(north)))
        return cls(family, float(info.landmark_size_m), {k: np.array(v, np.float64) for k, v in by_id.items()})

    def cells(self, cell_size_m: float, width: int, height: int) -> set[Cell]:
        """Grid cells a landmark (with its quiet zone) covers: known shelf, never a robot."""
        half = QUIET_ZONE * self.size_m / 2
        out: set[Cell] = set()
        for centres in self.by_id.values():
            for east, north in centres:
                # A hair inside the block, so that a block edge on a cell edge takes no extra cell.
                u0, u1 = (east - half) / cell_size_m + 1e-6, (east + half) / cell_size_m - 1e-6
                v0, v1 = (-north - half) / cell_size_m + 1e-6, (-north + half) / cell_size_m - 1e-6
                for x in range(max(0, math.floor(u0)), min(width, math.ceil(u1))):
                    for y in range(max(0, math.floor(v0)), min(height, math.ceil(v1))):
                        out.add((x, y))
        return out


@dataclass(frozen=True)
class CameraPoseEstimate:
    north_m: float
    east_m: float
    down_m: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float


@dataclass(frozen=True, eq=False)
class Registration:
    """Floor (cells: u = east/c, v = -north/c) -> undistorted pixels, and how it was found."""
    H: np.ndarray
    source: str                            # "landmarks" (from the image) or "estimate" (the frame's pose)
    landmarks: int = 0                     # landmarks used (RANSAC inliers)
    reprojection_px: float | None = None   # RMS over their corners
    pose: CameraPoseEstimate | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def registered(self) -> bool:
        return self.source == "landmarks"


def _body_to_ned(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def _floor_homography(K: np.ndarray, ned_to_cam: np.ndarray, position_ned: np.ndarray, cell_size_m: float
                      ) -> np.ndarray:
    # Floor point (u, v) in cells is NED (-v c, u c, 0).
    floor_to_ned = np.array([[0.0, -cell_size_m, 0.0], [cell_size_m, 0.0, 0.0], [0.0, 0.0, 0.0]])
    M = ned_to_cam @ floor_to_ned
    M[:, 2] -= ned_to_cam @ position_ned
    return K @ M


def homography(meta: CameraFrame, cell_size_m: float) -> np.ndarray:
    """Floor cells -> pixels from the frame's own pose estimate and attitude (the prior)."""
    roll, pitch = float(getattr(meta, "roll_rad", 0.0)), float(getattr(meta, "pitch_rad", 0.0))
    numbers = (meta.fx, meta.fy, meta.cx, meta.cy, meta.north_m, meta.east_m, meta.down_m, meta.yaw_rad, roll, pitch)
    if not all(math.isfinite(v) for v in numbers) or meta.fx <= 0 or meta.fy <= 0:
        raise ProtocolError(f"frame at t={meta.time_s:.2f}s: pose or intrinsics are not finite, positive numbers")
    if not meta.down_m < 0:
        raise MissionError(f"frame at t={meta.time_s:.2f}s: camera down={meta.down_m} m is not above the floor")
    cam_to_ned = _body_to_ned(roll, pitch, meta.yaw_rad) @ _CAMERA_IN_BODY
    return _floor_homography(intrinsics(meta), cam_to_ned.T, np.array([meta.north_m, meta.east_m, meta.down_m]),
                             cell_size_m)


@lru_cache(maxsize=16)
def _detector(family: str, perimeter_rate: float) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    # The altitude fixes a landmark's size in pixels: skipping candidates far off it
    # (shelf edges, robot markers) makes detection several times faster.
    params.minMarkerPerimeterRate = max(0.005, 0.5 * perimeter_rate)
    params.maxMarkerPerimeterRate = min(4.0, 2.0 * perimeter_rate)
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family)), params)


def _corners_floor(centre_en: np.ndarray, size_m: float, cell_size_m: float) -> np.ndarray:
    """A landmark's four corners in ArUco order (top-left, top-right, bottom-right,
    bottom-left; its top faces north) as floor cells (u, v)."""
    u, v, h = centre_en[0] / cell_size_m, -centre_en[1] / cell_size_m, size_m / 2 / cell_size_m
    return np.array([[u - h, v - h], [u + h, v - h], [u + h, v + h], [u - h, v + h]])


def _pose_from(rvec: np.ndarray, tvec: np.ndarray) -> tuple[np.ndarray, CameraPoseEstimate]:
    R, _ = cv2.Rodrigues(rvec)                 # NED -> camera
    position = (-R.T @ tvec).ravel()
    body = R.T @ _CAMERA_IN_BODY.T             # body -> NED
    pitch = -math.asin(max(-1.0, min(1.0, body[2, 0])))
    roll = math.atan2(body[2, 1], body[2, 2])
    yaw = math.atan2(body[1, 0], body[0, 0])
    return R, CameraPoseEstimate(float(position[0]), float(position[1]), float(position[2]), roll, pitch, yaw)


def register(gray: np.ndarray, meta: CameraFrame, landmarks: Landmarks | None, cell_size_m: float) -> Registration:
    """The floor homography of one undistorted grey image; from landmarks when enough are seen."""
    prior = homography(meta, cell_size_m)
    if landmarks is None:
        return Registration(prior, "estimate", notes=["no surveyed landmarks"])
    K = intrinsics(meta)
    side_px = landmarks.size_m * min(meta.fx, meta.fy) / max(-meta.down_m, 1e-6)
    corners, ids, _ = _detector(landmarks.family, round(4 * side_px / max(gray.shape), 4)).detectMarkers(gray)
    if ids is None:
        return Registration(prior, "estimate", notes=["no landmark in view"])
    prior_inv = np.linalg.inv(prior)
    # How far the estimate may put a landmark from where it is: position error plus
    # the yaw error swung over the footprint, generously.
    alt = -meta.down_m
    gate_m = 2.0 + 4.0 * (getattr(meta, "pose_sigma_m", 0.0) + alt * math.radians(getattr(meta, "yaw_sigma_deg", 0.0)
                                                                                      + 2.0))
    floor_pts, image_pts, names = [], [], []
    for quad, lid in zip(corners, ids.ravel().tolist()):
        table = landmarks.by_id.get(int(lid))
        if table is None:
            continue
        quad = quad.reshape(4, 2).astype(np.float64)
        u, v = cv2.perspectiveTransform(quad.mean(axis=0).reshape(1, 1, 2), prior_inv).ravel()
        predicted = np.array([u * cell_size_m, -v * cell_size_m])
        d = np.linalg.norm(table - predicted, axis=1)
        k = int(d.argmin())
        if d[k] > gate_m:
            continue
        floor_pts.append(_corners_floor(table[k], landmarks.size_m, cell_size_m))
        image_pts.append(quad)
        names.append((int(lid), k))
    if len(set(names)) < MIN_LANDMARKS:
        return Registration(prior, "estimate", notes=[f"{len(set(names))} landmark(s) in view, "
                                                      f"{MIN_LANDMARKS} needed"])
    floor = np.concatenate(floor_pts)
    image = np.concatenate(image_pts)
    _, mask = cv2.findHomography(floor, image, cv2.RANSAC, RANSAC_PX)
    inliers = mask.ravel().astype(bool) if mask is not None else np.zeros(len(floor), bool)
    used = {names[i // 4] for i in np.nonzero(inliers)[0]}
    if len(used) < MIN_LANDMARKS:
        return Registration(prior, "estimate", notes=["landmarks disagree (RANSAC)"])
    ned = np.column_stack([-floor[inliers, 1] * cell_size_m, floor[inliers, 0] * cell_size_m,
                           np.zeros(int(inliers.sum()))])
    ok, rvec, tvec = cv2.solvePnP(ned, image[inliers], K, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return Registration(prior, "estimate", notes=["solvePnP failed"])
    rvec, tvec = cv2.solvePnPRefineLM(ned, image[inliers], K, None, rvec, tvec)
    R, pose = _pose_from(rvec, tvec)
    if not pose.down_m < 0:
        return Registration(prior, "estimate", notes=["landmarks put the camera under the floor"])
    H = _floor_homography(K, R, np.array([pose.north_m, pose.east_m, pose.down_m]), cell_size_m)
    projected = cv2.perspectiveTransform(floor[inliers].reshape(-1, 1, 2), H).reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum((projected - image[inliers]) ** 2, axis=1))))
    if rms > MAX_REPROJECTION_PX:
        return Registration(prior, "estimate", landmarks=len(used), reprojection_px=rms,
                            notes=[f"landmark fit {rms:.1f} px RMS, over {MAX_REPROJECTION_PX} px"])
    return Registration(H, "landmarks", landmarks=len(used), reprojection_px=rms, pose=pose)
