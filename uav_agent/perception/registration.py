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
from functools import cached_property, lru_cache

import cv2
import numpy as np

from protocol.errors import MissionError, ProtocolError
from protocol.grid import Cell
from protocol.messages import CameraFrame, WorldInfo

from .frames import intrinsics

MIN_LANDMARKS = 2          # one small marker under blur leaves the yaw loose by degrees
SINGLE_LANDMARK_PX = 40.0  # a landmark this many pixels wide registers an image alone
SINGLE_TRUST = 0.15        # cells of trusted radius per pixel of a lone landmark's side
FULL_POSE_LANDMARKS = 3    # from this many, the tilt too comes from the image
LEVEL_RANSAC_M = 0.1       # inlier threshold of the level fit, metres on the floor
REFIT_ROUNDS = 3           # of the full pose: inliers again by the refined pose, refined again
MAX_REPROJECTION_PX = 2.5  # an accepted registration's RMS error over its inliers
QUIET_ZONE = 1 / 0.75      # a landmark's white block, as a multiple of its black square's side
TILE_CONTEXT_PX = 32       # around a landmark's block in its detection tile: the widest threshold window and more

# Camera axes (columns) in the vehicle's body frame (x forward, y right, z down):
# a nadir camera whose image right is the body's right and image up its nose.
_CAMERA_IN_BODY = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

MIN_CANDIDATE_STD = 15.0   # grey std inside a marker candidate (a marker's is ~100, a blank square's noise < 10)
# One adaptive-threshold window of about two modules (a 4x4 landmark is 6 modules wide with its
# border) instead of OpenCV's three (3, 13, 23 px): on the 450's survey, 0.7 of the detector's time,
# the same landmarks found and the same reprojection error; under blur 2, noise 10 and lighting
# 0.5 0.45 of its time, as many landmarks, a lower error (bench-results/mission/survey-realistic-450.md).
THRESHOLD_WINDOW = 0.3     # of a landmark's side in pixels


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

    @cached_property
    def table(self) -> tuple[np.ndarray, np.ndarray]:
        """Every instance as (ids [n], (east_m, north_m) [n, 2])."""
        ids = np.concatenate([np.full(len(v), k, np.int64) for k, v in self.by_id.items()] or [np.zeros(0, np.int64)])
        centres = np.concatenate([v.reshape(-1, 2) for v in self.by_id.values()] or [np.zeros((0, 2))])
        return ids, centres

    @property
    def module_m(self) -> float:
        """Side of one module of a landmark (its black square is markerSize + 2 modules wide)."""
        bits = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.family)).markerSize
        return self.size_m / (bits + 2)

    def view_alt_m(self, footprint_per_m: float) -> float:
        """Height from which an image `footprint_per_m` metres wide per metre of height spans
        2.5 landmark spacings (the median distance between neighbours): two or more in view."""
        pts = np.concatenate(list(self.by_id.values()))
        if len(pts) < 2:
            return 0.0
        d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=2) if len(pts) <= 2000 else None
        if d is None:   # a big table: neighbours within a sample are enough for a median
            sample = pts[:: max(1, len(pts) // 1000)]
            d = np.linalg.norm(sample[:, None, :] - pts[None, :, :], axis=2)
        d[d == 0] = np.inf
        return float(2.5 * np.median(d.min(axis=1)) / footprint_per_m)

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
    anchors: np.ndarray | None = None      # (k, 2) floor cells of the landmarks used
    trust_radius: float = math.inf         # cells from an anchor within which the placement holds

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
def _parameters(perimeter_rate: float, window: int) -> cv2.aruco.DetectorParameters:
    params = cv2.aruco.DetectorParameters()
    params.adaptiveThreshWinSizeMin = params.adaptiveThreshWinSizeMax = window
    # The altitude fixes a landmark's size in pixels: skipping candidates far off it
    # (shelf edges, robot markers) makes detection several times faster.
    params.minMarkerPerimeterRate = max(0.005, 0.5 * perimeter_rate)
    params.maxMarkerPerimeterRate = min(4.0, 2.0 * perimeter_rate)
    # A marker's inside is black and white; a plain shelf or floor square is not worth decoding
    # (each decode searches the whole dictionary: thousands of shelf squares cost seconds).
    params.minOtsuStdDev = MIN_CANDIDATE_STD
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    # The family's full correction (OpenCV uses 60 % of it by default): a blurred landmark often
    # reads two bits off, and a misread cannot pass for another landmark here, since each id is
    # matched only within the gate of where the prior puts it, and the fit's RANSAC drops the rest.
    params.errorCorrectionRate = 1.0
    # Each bit read from its cell's middle, 8 px a cell: sampled at OpenCV's 4 px with 13 %
    # margins, a blurred bit is mostly its neighbours' spill, and at the combined target a
    # 46 px landmark was read in 13 of 40 noise draws; 40 of 40 so.
    params.perspectiveRemovePixelPerCell = 8
    params.perspectiveRemoveIgnoredMarginPerCell = 0.3
    return params


def _in_reach(landmarks: Landmarks, prior_inv: np.ndarray, box: tuple[int, int, int, int], gate_m: float,
              cell_size_m: float) -> np.ndarray | None:
    """Sorted ids of the landmarks a detection centred in the pixel box (x0, y0, x1, y1) could be
    matched to: an instance within the gate of the floor the prior says the box covers.
    None: the prior sees the horizon there."""
    x0, y0, x1, y1 = box
    corners = np.array([[x0, y0, 1], [x1, y0, 1], [x0, y1, 1], [x1, y1, 1]], np.float64) @ prior_inv.T
    if not np.all(corners[:, 2] > 0):
        return None
    uv = corners[:, :2] / corners[:, 2:3]
    # Floor (east, north) metres of the box's bounding box on the floor, widened by the gate.
    en = np.column_stack([uv[:, 0] * cell_size_m, -uv[:, 1] * cell_size_m])
    ids, centres = landmarks.table
    near = np.all((centres >= en.min(axis=0) - gate_m) & (centres <= en.max(axis=0) + gate_m), axis=1)
    return np.unique(ids[near])


def _window(side_px: float) -> int:
    """The adaptive threshold's window for landmarks `side_px` wide: odd, 3 at least."""
    return max(3, 2 * round(THRESHOLD_WINDOW * side_px / 2 - 0.5) + 1)


def _detect(gray: np.ndarray, family: str, perimeter_px: float, ids: np.ndarray | None
            ) -> tuple[list[np.ndarray], list[int]]:
    """Landmark corners and ids in `gray`, decoded against only `ids` (None: the whole family).

    Decoding searches the dictionary for every candidate square, and with a thousand codes
    that search is most of the detector's time; the few codes that can be in view give the
    same answers, since a code within the detector's correction of a read is the only one."""
    full = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family))
    rate = round(perimeter_px / max(gray.shape), 4)
    if ids is None:
        ids = np.arange(full.bytesList.shape[0])
        dictionary = full
    else:
        ids = ids[(ids >= 0) & (ids < full.bytesList.shape[0])]
        if ids.size == 0:
            return [], []
        dictionary = cv2.aruco.Dictionary(full.bytesList[ids], full.markerSize, full.maxCorrectionBits)
    params = _parameters(rate, _window(perimeter_px / 4))
    corners, found, _ = cv2.aruco.ArucoDetector(dictionary, params).detectMarkers(gray)
    return [c.reshape(4, 2) for c in corners], [] if found is None else ids[found.ravel()].tolist()


def _detect_tiled(gray: np.ndarray, landmarks: Landmarks, prior_inv: np.ndarray, gate_m: float, cell_size_m: float,
                  side_px: float, alt_m: float, f_px: float) -> tuple[list[np.ndarray], list[int]]:
    """`_detect` over tiles of the image, each decoding only the codes in reach of its own part
    of the floor (the gate is tens of metres, a 12 MP footprint a couple of hundred).

    Each tile is read with a margin wider than a landmark's block plus the detector's widest
    threshold window, and keeps the landmarks centred in its core: every landmark is read by
    exactly one tile, with the same surroundings as in the whole image."""
    img_h, img_w = gray.shape
    margin = math.ceil(QUIET_ZONE * side_px / 2) + max(TILE_CONTEXT_PX, _window(side_px))
    core = max(4 * margin, round(2 * gate_m * f_px / max(alt_m, 1e-6)))
    nx, ny = max(1, round(img_w / core)), max(1, round(img_h / core))
    xs = np.linspace(0, img_w, nx + 1).round().astype(int)
    ys = np.linspace(0, img_h, ny + 1).round().astype(int)
    corners: list[np.ndarray] = []
    ids: list[int] = []
    for y0, y1 in zip(ys[:-1], ys[1:]):
        for x0, x1 in zip(xs[:-1], xs[1:]):
            reach = _in_reach(landmarks, prior_inv, (x0, y0, x1, y1), gate_m, cell_size_m)
            if reach is not None and reach.size == 0:
                continue
            ox, oy = max(0, x0 - margin), max(0, y0 - margin)
            tile = gray[oy:min(img_h, y1 + margin), ox:min(img_w, x1 + margin)]
            for quad, lid in zip(*_detect(tile, landmarks.family, 4 * side_px, reach)):
                quad = quad.astype(np.float64) + (ox, oy)
                cx, cy = quad.mean(axis=0)
                if x0 <= cx < x1 and y0 <= cy < y1:
                    corners.append(quad)
                    ids.append(lid)
    return corners, ids


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
    prior_inv = np.linalg.inv(prior)
    # How far the estimate may put a landmark from where it is: position error plus
    # the yaw error swung over the footprint, generously.
    alt = -meta.down_m
    gate_m = 2.0 + 4.0 * (getattr(meta, "pose_sigma_m", 0.0) + alt * math.radians(getattr(meta, "yaw_sigma_deg", 0.0)
                                                                                      + 2.0))
    corners, ids = _detect_tiled(gray, landmarks, prior_inv, gate_m, cell_size_m, side_px, alt, min(meta.fx, meta.fy))
    if not ids:
        return Registration(prior, "estimate", notes=["no landmark in view"])
    floor_pts, image_pts, names = [], [], []
    for quad, lid in zip(corners, ids):
        table = landmarks.by_id.get(int(lid))
        if table is None:
            continue
        u, v = cv2.perspectiveTransform(quad.mean(axis=0).reshape(1, 1, 2), prior_inv).ravel()
        predicted = np.array([u * cell_size_m, -v * cell_size_m])
        d = np.linalg.norm(table - predicted, axis=1)
        k = int(d.argmin())
        if d[k] > gate_m:
            continue
        floor_pts.append(_corners_floor(table[k], landmarks.size_m, cell_size_m))
        image_pts.append(quad)
        names.append((int(lid), k))
    # One landmark's corners fix the yaw to within (corner error / its side): enough when it is large.
    least = 1 if side_px >= SINGLE_LANDMARK_PX else MIN_LANDMARKS
    if len(set(names)) < least:
        return Registration(prior, "estimate", notes=[f"{len(set(names))} landmark(s) in view, "
                                                      f"{least} needed"])
    floor = np.concatenate(floor_pts)
    image = np.concatenate(image_pts)
    ned = np.column_stack([-floor[:, 1] * cell_size_m, floor[:, 0] * cell_size_m, np.zeros(len(floor))])
    level = _level_fit(ned, image, meta)
    if level is None:
        return Registration(prior, "estimate", notes=["landmarks disagree (RANSAC)"])
    R, pose, inliers = level
    used = {names[i // 4] for i in np.nonzero(inliers)[0]}
    solver = "level"
    # Three or more landmarks spread over the image pin the tilt better than the
    # vehicle's attitude estimate: refine all six degrees of freedom from the level fit.
    if len(used) >= FULL_POSE_LANDMARKS:
        rvec, _ = cv2.Rodrigues(R)
        tvec = -R @ np.array([pose.north_m, pose.east_m, pose.down_m])
        rvec, tvec = cv2.solvePnPRefineLM(ned[inliers], image[inliers], K, None, rvec, tvec.reshape(3, 1))
        R6, pose6 = _pose_from(rvec, tvec)
        if _rms(ned[inliers], image[inliers], K, R6, pose6) < _rms(ned[inliers], image[inliers], K, R, pose):
            R, pose, solver = R6, pose6, "full"
            # The level fit's inliers lean to where its assumed tilt fits best, and which those
            # are depends on RANSAC's draw (the landmarks' order); with the tilt solved, the
            # landmarks that agree with the pose are the inliers, whatever was drawn.
            tol_px = LEVEL_RANSAC_M * min(K[0, 0], K[1, 1]) / max(-pose.down_m, 1e-6)
            for _ in range(REFIT_ROUNDS):
                agree = np.repeat(_residuals(ned, image, K, R, pose).reshape(-1, 4).max(axis=1) < tol_px, 4)
                if np.array_equal(agree, inliers) or agree.sum() < 4 * FULL_POSE_LANDMARKS:
                    break
                inliers = agree
                rvec, tvec = cv2.solvePnPRefineLM(ned[inliers], image[inliers], K, None, rvec, tvec)
                R, pose = _pose_from(rvec, tvec)
            used = {names[i // 4] for i in np.nonzero(inliers)[0]}
    rms = _rms(ned[inliers], image[inliers], K, R, pose)
    if not pose.down_m < 0:
        return Registration(prior, "estimate", notes=["landmarks put the camera under the floor"])
    if rms > MAX_REPROJECTION_PX:
        return Registration(prior, "estimate", landmarks=len(used), reprojection_px=rms,
                            notes=[f"landmark fit {rms:.1f} px RMS, over {MAX_REPROJECTION_PX} px"])
    H = _floor_homography(K, R, np.array([pose.north_m, pose.east_m, pose.down_m]), cell_size_m)
    anchors = np.array([floor[i * 4: i * 4 + 4].mean(axis=0) for i, name in enumerate(names) if name in used])
    # One landmark leaves the yaw uncertain by about a pixel over its side: the placement
    # drifts with distance from it, a tenth of a cell at SINGLE_TRUST cells per pixel of side.
    radius = SINGLE_TRUST * side_px if len(used) == 1 else math.inf
    return Registration(H, "landmarks", landmarks=len(used), reprojection_px=rms, pose=pose, notes=[solver],
                        anchors=anchors, trust_radius=radius)


def _residuals(ned: np.ndarray, image: np.ndarray, K: np.ndarray, R: np.ndarray, pose: CameraPoseEstimate
               ) -> np.ndarray:
    """Each point's reprojection error, pixels."""
    cam = (ned - np.array([pose.north_m, pose.east_m, pose.down_m])) @ R.T
    px = cam[:, :2] / cam[:, 2:3] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    return np.sqrt(np.sum((px - image) ** 2, axis=1))


def _rms(ned: np.ndarray, image: np.ndarray, K: np.ndarray, R: np.ndarray, pose: CameraPoseEstimate) -> float:
    return float(np.sqrt(np.mean(_residuals(ned, image, K, R, pose) ** 2)))


def _level_fit(ned: np.ndarray, image: np.ndarray, meta: CameraFrame
               ) -> tuple[np.ndarray, CameraPoseEstimate, np.ndarray] | None:
    """Position, height and yaw from floor points, the roll and pitch taken from the estimate.

    Each pixel's ray is turned by the estimated roll and pitch into a level camera,
    whose view of the floor is a similarity: scale = height, rotation = yaw, shift =
    position. A 4-parameter RANSAC fit (cv2.estimateAffinePartial2D) is well posed
    with a single landmark, where a full 6-DOF pose trades tilt for position."""
    roll, pitch = float(getattr(meta, "roll_rad", 0.0)), float(getattr(meta, "pitch_rad", 0.0))
    K = intrinsics(meta)
    rays = np.column_stack([(image[:, 0] - K[0, 2]) / K[0, 0], (image[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(image))])
    tilt = _body_to_ned(roll, pitch, 0.0) @ _CAMERA_IN_BODY      # camera -> a yaw-free level frame
    d = rays @ tilt.T
    if np.any(d[:, 2] <= 1e-6):
        return None
    q = d[:, :2] / d[:, 2:3]          # (north, east) offsets per metre of height, yaw-free
    M, mask = cv2.estimateAffinePartial2D(np.ascontiguousarray(q), np.ascontiguousarray(ned[:, :2]), method=cv2.RANSAC,
                                          ransacReprojThreshold=LEVEL_RANSAC_M, confidence=0.999)
    if M is None:
        return None
    height = math.hypot(M[0, 0], M[1, 0])
    yaw = math.atan2(M[1, 0], M[0, 0])
    north, east = float(M[0, 2]), float(M[1, 2])
    if not height > 0:
        return None
    body = _body_to_ned(roll, pitch, yaw)
    R = (body @ _CAMERA_IN_BODY).T
    pose = CameraPoseEstimate(north, east, -height, roll, pitch, yaw)
    return R, pose, mask.ravel().astype(bool)
