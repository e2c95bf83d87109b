"""What the camera sees: the floor's texture warped into the image through the camera's
full pose (position, yaw, pitch, roll), then through the lens's distortion.

A view of the floor plane is a homography of it, so a frame is rendered by
drawing only the visible cells as a flat texture and warping that texture into
the image with `cv2.warpPerspective`: the cost follows the image size, not the
size of the warehouse. A distorting lens is rendered as a slightly wider pinhole
image remapped through a cached per-pixel map (the inverse of OpenCV's
Brown-Conrady model, so `cv2.undistortPoints` with the published coefficients
undoes it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np

from protocol.errors import MapError, MissionError
from protocol.grid import Cell, on_grid
from scenarios.landmarks import LandmarkSet

from ..movers import FORKLIFT, PALLET, PERSON
from .degrade import degrade
from .fields import upsample
from .model import CameraModel

# BGR colours. The floor is bright and colourless, shelves dark and brown, goals
# saturated green, the world outside the grid dark blue: each is separable by
# brightness or hue alone, under a lighting gradient too.
FLOOR_BGR = (215, 215, 215)
SHELF_BGR = (45, 60, 80)
OUTSIDE_BGR = (110, 45, 35)
GOAL_BGR = (60, 220, 60)
GOAL_RING_BGR = (25, 70, 25)
MARKER_QUIET_BGR = (255, 255, 255)
# The uncooperative movers (sim_world.movers) carry no marker: they are told apart by colour,
# each a saturated hue nothing else on the floor has (shelves are brown but dark, the outside
# blue but dark, goals green), and as bright as a goal pad or brighter (grey level >= 150, over
# twice a shelf's 64), so the occupancy split still reads their cell as floor. Hues (OpenCV,
# 0..180), the contract uav_agent.perception.movers reads them by: a person ~9 (a hi-vis
# orange vest seen from above), a forklift ~24 (safety yellow), a pallet ~154 (magenta plastic:
# blue, the usual plastic pallet, would share the outside's hue and differ from it only in a
# brightness the lighting gradient erodes). Lighting and vignetting scale all three channels
# alike and leave the hue as it is.
PERSON_BGR = (60, 120, 255)
FORKLIFT_BGR = (0, 200, 255)
FORK_TINE_BGR = (90, 90, 90)      # the forks: mid grey, a marker's contrast they must not reach
PALLET_BGR = (230, 100, 250)

ARUCO_DICTIONARY = cv2.aruco.DICT_4X4_1000
MARKER_IDS = 1000          # ids 0..999 exist in DICT_4X4_1000
# A robot cell is 8 units wide: one unit of white quiet zone around a 6-unit
# marker (4x4 data bits + a 1-bit black border), so marker modules stay whole
# texture pixels and neighbouring markers never touch.
CELL_UNITS = 8
MARKER_UNITS = 6
GOAL_RADIUS = 0.38         # of a cell, the green disc
GOAL_RING = 0.07           # of a cell, the dark ring around it
# The pad layout (Scene.goal_pads), where a robot on a goal stays recognisable as one: the goal a
# green square pad of GOAL_PAD cell, the robot a white square body of ROBOT_BODY cell centred in
# its cell, and on the body its marker (4x4 data + 1-module black border = 6 modules) with half a
# module of white around it: module = ROBOT_BODY / 7 cell, marker side = 6/7 of the body.
# On a goal a green frame of (GOAL_PAD - ROBOT_BODY) / 2 = 0.08 cell shows around the body.
GOAL_PAD = 0.96
ROBOT_BODY = 0.8
BODY_MODULES = 7           # across the body: 6 marker modules + 2 half-module margins
# Movers, in cells, centred in their cell: a person a disc (shoulders and vest); a forklift a
# body nearly filling its cell with its two forks ahead of it (north: the scene has no heading);
# a pallet a square.
PERSON_DIAMETER = 0.58
FORKLIFT_BODY = (0.86, 0.62)      # across, along
FORK_TINE = (0.09, 0.28)          # each fork's width and length, beyond the body's front
FORK_GAP = 0.3                    # between the forks' centres
PALLET_SIDE = 0.8
MOVER_KINDS = (PERSON, FORKLIFT, PALLET)
MAX_TEXTURE_PX = 8192
MAP_STEP_PX = 8            # the distortion map is computed every 8 pixels and interpolated (error ~0.001 px)


class CameraPose(NamedTuple):
    north_m: float
    east_m: float
    down_m: float   # negative: above the floor
    yaw_rad: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0


def as_pose(pose: CameraPose | tuple) -> CameraPose:
    """Any (north, east, down[, yaw[, roll[, pitch]]]) tuple as a CameraPose."""
    p = CameraPose(*(float(v) for v in tuple(pose)[:6]))
    if not all(math.isfinite(v) for v in p):
        raise MissionError(f"camera: pose {tuple(pose)} is not finite")
    return p


@dataclass(frozen=True, eq=False)
class Scene:
    """What is physically on the floor: the grid, robots by marker id, goal markers, the surveyed
    landmarks (on shelf tops and just outside the border; None = a bare floor), and the people,
    forklifts and pallets standing on it."""
    free: np.ndarray                       # bool [height, width], True = floor
    robots: dict[int, Cell] = field(default_factory=dict)
    goals: list[Cell] = field(default_factory=list)
    landmarks: LandmarkSet | None = None
    goal_pads: bool = False                # the pad layout (see GOAL_PAD); False = goal discs, full-cell tags
    movers: tuple[tuple[str, Cell], ...] = ()   # (kind, cell): people, forklifts, pallets, drawn over all else

    def __post_init__(self) -> None:
        free = np.asarray(self.free)
        if free.ndim != 2 or free.size == 0 or free.dtype != bool:
            raise MapError(f"scene: the grid must be a non-empty 2-D bool array, got {free.dtype} {free.shape}")
        h, w = free.shape
        for rid, (x, y) in self.robots.items():
            if not 0 <= rid < MARKER_IDS:
                raise MapError(f"scene: robot id {rid} has no marker (DICT_4X4_1000 holds ids 0..{MARKER_IDS - 1})")
            if not on_grid(x, y, w, h):
                raise MapError(f"scene: robot {rid} at {(x, y)} is off the {w}x{h} grid")
        for x, y in self.goals:
            if not on_grid(x, y, w, h):
                raise MapError(f"scene: goal {(x, y)} is off the {w}x{h} grid")
        for kind, (x, y) in self.movers:
            if kind not in MOVER_KINDS:
                raise MapError(f"scene: mover kind {kind!r} is none of {', '.join(MOVER_KINDS)}")
            if not on_grid(x, y, w, h):
                raise MapError(f"scene: {kind} at {(x, y)} is off the {w}x{h} grid")


def camera_rotation(yaw: float, roll: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """NED -> camera axes (x image right, y image down, z optical axis). The camera is fixed
    to the body looking down, image up = the nose: R = C @ (Rz(yaw) Ry(pitch) Rx(roll))^T."""
    s, co = math.sin(yaw), math.cos(yaw)
    if roll == 0.0 and pitch == 0.0:
        return np.array([[-s, co, 0.0], [-co, -s, 0.0], [0.0, 0.0, 1.0]])
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    rz = np.array([[co, -s, 0.0], [s, co, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    body_to_cam = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return body_to_cam @ (rz @ ry @ rx).T


def _homography(pose: CameraPose, K: np.ndarray, cell_size_m: float) -> np.ndarray:
    if not pose.down_m < 0:
        raise MissionError(f"camera: pose down={pose.down_m} m is not above the floor (down must be negative)")
    if not cell_size_m > 0:
        raise MapError(f"cell size must be positive, got {cell_size_m}")
    R = camera_rotation(pose.yaw_rad, pose.roll_rad, pose.pitch_rad)
    floor_to_ned = np.array([[0.0, -cell_size_m, 0.0], [cell_size_m, 0.0, 0.0], [0.0, 0.0, 0.0]])
    M = R @ floor_to_ned
    M[:, 2] -= R @ np.array([pose.north_m, pose.east_m, pose.down_m], dtype=float)
    return K @ M


def floor_homography(pose: CameraPose | tuple, model: CameraModel, cell_size_m: float) -> np.ndarray:
    """3x3 map from floor coordinates in cells (u = east/c, v = -north/c) to pinhole image
    pixels (before the lens's distortion, which `cv2.undistortPoints` removes)."""
    return _homography(as_pose(pose), model.K, cell_size_m)


def _texture_ppc(image_ppc: float) -> int:
    """Texture pixels per cell: a multiple of CELL_UNITS, about 1.5x the image's
    resolution so the warp interpolates instead of skipping marker modules."""
    units = max(1, math.ceil(1.5 * image_ppc / CELL_UNITS))
    return CELL_UNITS * min(units, 24)


@lru_cache(maxsize=4096)
def _marker(robot_id: int, module_px: int) -> np.ndarray:
    dictionary = cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY)
    img = cv2.aruco.generateImageMarker(dictionary, robot_id, MARKER_UNITS * module_px, borderBits=1)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    img.flags.writeable = False
    return img


@lru_cache(maxsize=8192)
def _landmark_marker(family: str, marker_id: int, side_px: int) -> np.ndarray:
    """A landmark's black square (border included) of exactly `side_px` texels: drawn at a whole
    number of texels per module, then area-resampled, so its size in metres is exact at any scale."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family))
    bits = dictionary.markerSize + 2
    module = max(1, math.ceil(side_px / bits))
    img = cv2.aruco.generateImageMarker(dictionary, marker_id, bits * module, borderBits=1)
    if img.shape[0] != side_px:
        img = cv2.resize(img, (side_px, side_px), interpolation=cv2.INTER_AREA)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    img.flags.writeable = False
    return img


def _draw_landmarks(tex: np.ndarray, marks: LandmarkSet, cell_size_m: float, x0: int, y0: int, ppc: int) -> None:
    """Each landmark: a white block (its quiet zone) with the black-bordered marker centred in it."""
    if not marks.landmarks:
        return
    centres = marks.centres_cells(cell_size_m)
    half = marks.block_cells / 2
    th, tw = tex.shape[:2]
    block_px = round(marks.block_cells * ppc)
    side_px = max(1, round(marks.size_m / cell_size_m * ppc))
    inset = (block_px - side_px) // 2
    for (lid, _, _), (u, v) in zip(marks.landmarks, centres):
        px, py = round((u - half - x0) * ppc), round((v - half - y0) * ppc)
        if px >= tw or py >= th or px + block_px <= 0 or py + block_px <= 0:
            continue
        block = np.empty((block_px, block_px, 3), np.uint8)
        block[:] = MARKER_QUIET_BGR
        block[inset:inset + side_px, inset:inset + side_px] = _landmark_marker(marks.family, lid, side_px)
        ox, oy = max(0, -px), max(0, -py)
        ex, ey = min(block_px, tw - px), min(block_px, th - py)
        tex[py + oy:py + ey, px + ox:px + ex] = block[oy:ey, ox:ex]


def _inside(x0: int, y0: int, x1: int, y1: int, w: int, h: int) -> np.ndarray:
    xs, ys = np.arange(x0, x1), np.arange(y0, y1)
    return ((xs >= 0) & (xs < w))[None, :] & ((ys >= 0) & (ys < h))[:, None]


def _texture(scene: Scene, x0: int, y0: int, x1: int, y1: int, ppc: int, cell_size_m: float = 1.0) -> np.ndarray:
    h, w = scene.free.shape
    cells = scene.free[max(0, y0):min(h, y1), max(0, x0):min(w, x1)]
    colours = np.where(cells[..., None], np.uint8(FLOOR_BGR), np.uint8(SHELF_BGR)).astype(np.uint8)
    if x0 < 0 or y0 < 0 or x1 > w or y1 > h:   # the walls around the grid, where the ring of landmarks is
        colours = np.pad(colours, ((max(0, -y0), max(0, y1 - h)), (max(0, -x0), max(0, x1 - w)), (0, 0)))
        colours[:, :] = np.where(_inside(x0, y0, x1, y1, w, h)[..., None], colours, np.uint8(OUTSIDE_BGR))
    tex = cv2.resize(colours, (colours.shape[1] * ppc, colours.shape[0] * ppc), interpolation=cv2.INTER_NEAREST_EXACT)
    if scene.goal_pads:
        _draw_pads(tex, scene, x0, y0, x1, y1, ppc)
    else:
        _draw_discs_and_tags(tex, scene, x0, y0, x1, y1, ppc)
    if scene.movers:
        _draw_movers(tex, scene.movers, x0, y0, x1, y1, ppc)
    if scene.landmarks is not None:
        _draw_landmarks(tex, scene.landmarks, cell_size_m, x0, y0, ppc)
    return tex


def _rect(tex: np.ndarray, cx: float, cy: float, width: float, height: float, colour: tuple[int, int, int]) -> None:
    """A filled axis-aligned rectangle centred at texel coordinates (cx, cy), edges anti-aliased."""
    shift = 4
    w, h = width / 2, height / 2
    pts = np.array([[cx - w, cy - h], [cx + w, cy - h], [cx + w, cy + h], [cx - w, cy + h]]) - 0.5
    cv2.fillConvexPoly(tex, np.round(pts * (1 << shift)).astype(np.int32), colour, cv2.LINE_AA, shift)


def _square(tex: np.ndarray, cx: float, cy: float, side: float, colour: tuple[int, int, int]) -> None:
    """A filled axis-aligned square centred at texel coordinates (cx, cy), edges anti-aliased."""
    _rect(tex, cx, cy, side, side, colour)


def _draw_movers(tex: np.ndarray, movers: tuple[tuple[str, Cell], ...], x0: int, y0: int, x1: int, y1: int,
                 ppc: int) -> None:
    """Each mover inside the texture's window over whatever its cell shows (a person or a
    forklift that meets a robot stands over it): a few anti-aliased draws each."""
    shift = 4
    for kind, (mx, my) in movers:
        if not (x0 <= mx < x1 and y0 <= my < y1):
            continue
        cx, cy = (mx - x0 + 0.5) * ppc, (my - y0 + 0.5) * ppc
        if kind == PERSON:
            centre = (round((cx - 0.5) * (1 << shift)), round((cy - 0.5) * (1 << shift)))
            cv2.circle(tex, centre, round(PERSON_DIAMETER / 2 * ppc * (1 << shift)), PERSON_BGR, -1, cv2.LINE_AA, shift)
        elif kind == FORKLIFT:
            across, along = FORKLIFT_BODY
            tine_w, tine_l = FORK_TINE
            # Body and forks together span along + tine_l, centred on the cell; the forks point north (-y).
            top = cy - (along + tine_l) / 2 * ppc
            _rect(tex, cx, top + (tine_l + along / 2) * ppc, across * ppc, along * ppc, FORKLIFT_BGR)
            for side in (-1, 1):
                _rect(tex, cx + side * FORK_GAP / 2 * ppc, top + tine_l / 2 * ppc, tine_w * ppc, tine_l * ppc,
                      FORK_TINE_BGR)
        else:
            _square(tex, cx, cy, PALLET_SIDE * ppc, PALLET_BGR)


@lru_cache(maxsize=4096)
def _body_marker(robot_id: int, side_px: int) -> np.ndarray:
    """A robot's marker of exactly `side_px` texels (area-resampled from whole-texel modules)."""
    module = max(1, math.ceil(side_px / MARKER_UNITS))
    img = _marker(robot_id, module)
    return img if img.shape[0] == side_px else cv2.resize(img, (side_px, side_px), interpolation=cv2.INTER_AREA)


def _draw_pads(tex: np.ndarray, scene: Scene, x0: int, y0: int, x1: int, y1: int, ppc: int) -> None:
    for gx, gy in scene.goals:
        if x0 <= gx < x1 and y0 <= gy < y1:
            _square(tex, (gx - x0 + 0.5) * ppc, (gy - y0 + 0.5) * ppc, GOAL_PAD * ppc, GOAL_BGR)
    side = round(ROBOT_BODY * MARKER_UNITS / BODY_MODULES * ppc)
    for rid, (rx, ry) in scene.robots.items():
        if x0 <= rx < x1 and y0 <= ry < y1:
            cx, cy = (rx - x0 + 0.5) * ppc, (ry - y0 + 0.5) * ppc
            _square(tex, cx, cy, ROBOT_BODY * ppc, MARKER_QUIET_BGR)
            if side >= MARKER_UNITS:
                px, py = round(cx - side / 2), round(cy - side / 2)
                tex[py:py + side, px:px + side] = _body_marker(rid, side)
            else:   # seen from so far that a module is under a texture pixel: a dark blob is all there is
                _square(tex, cx, cy, ppc / 2, (0, 0, 0))


def _draw_discs_and_tags(tex: np.ndarray, scene: Scene, x0: int, y0: int, x1: int, y1: int, ppc: int) -> None:
    shift = 4  # sub-pixel circle centres
    for gx, gy in scene.goals:
        if x0 <= gx < x1 and y0 <= gy < y1:
            centre = (round(((gx - x0) * ppc + ppc / 2 - 0.5) * 16), round(((gy - y0) * ppc + ppc / 2 - 0.5) * 16))
            cv2.circle(tex, centre, round((GOAL_RADIUS + GOAL_RING / 2) * ppc * 16), GOAL_RING_BGR, -1, cv2.LINE_AA, shift)
            cv2.circle(tex, centre, round((GOAL_RADIUS - GOAL_RING / 2) * ppc * 16), GOAL_BGR, -1, cv2.LINE_AA, shift)
    unit = ppc // CELL_UNITS
    for rid, (rx, ry) in scene.robots.items():
        if x0 <= rx < x1 and y0 <= ry < y1:
            px, py = (rx - x0) * ppc, (ry - y0) * ppc
            tex[py:py + ppc, px:px + ppc] = MARKER_QUIET_BGR
            if unit:
                tex[py + unit:py + (CELL_UNITS - 1) * unit, px + unit:px + (CELL_UNITS - 1) * unit] = _marker(rid, unit)
            else:   # seen from so far that a module is under a texture pixel: a dark blob is all there is
                tex[py + ppc // 4:py + ppc - ppc // 4, px + ppc // 4:px + ppc - ppc // 4] = 0


class Roi(NamedTuple):
    """A region of the sensor, in pixels: its top-left corner and size."""
    x: int
    y: int
    width: int
    height: int


def clip_roi(model: CameraModel, x: int, y: int, width: int, height: int) -> Roi | None:
    """The requested region within the sensor; None for the whole image (0 wide or high, or a
    region that covers it all)."""
    if width <= 0 or height <= 0:
        return None
    x0, y0 = min(max(0, x), model.width - 1), min(max(0, y), model.height - 1)
    roi = Roi(x0, y0, min(width, model.width - x0), min(height, model.height - y0))
    return None if (roi.width, roi.height) == (model.width, model.height) else roi


class _Lens(NamedTuple):
    """A distorting lens as a remap: the pinhole canvas to render, and where each output pixel samples it."""
    K: np.ndarray            # the canvas's pinhole intrinsics
    size: tuple[int, int]    # canvas (width, height)
    map1: np.ndarray         # cv2.remap maps in fixed point (CV_16SC2 + CV_16UC1)
    map2: np.ndarray


@lru_cache(maxsize=4)
def _lens(width: int, height: int, fx: float, fy: float, cx: float, cy: float,
          dist: tuple[float, float, float, float, float]) -> _Lens:
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    step = MAP_STEP_PX
    gy, gx = np.mgrid[0:height + step:step, 0:width + step:step].astype(np.float32)
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6)
    src = cv2.undistortPoints(pts, K, np.array(dist), None, K, criteria=criteria).reshape(gy.shape + (2,))
    full = upsample(src, step, width, height)
    x_lo, y_lo = math.floor(float(full[..., 0].min())) - 2, math.floor(float(full[..., 1].min())) - 2
    x_hi, y_hi = math.ceil(float(full[..., 0].max())) + 2, math.ceil(float(full[..., 1].max())) + 2
    full[..., 0] -= x_lo
    full[..., 1] -= y_lo
    canvas_K = K.copy()
    canvas_K[0, 2] -= x_lo
    canvas_K[1, 2] -= y_lo
    map1, map2 = cv2.convertMaps(full, None, cv2.CV_16SC2)
    return _Lens(canvas_K, (x_hi - x_lo + 1, y_hi - y_lo + 1), map1, map2)


def lens_for(model: CameraModel) -> _Lens | None:
    if not model.distorted:
        return None
    return _lens(model.width, model.height, model.fx, model.fy, model.cx, model.cy,
                 tuple(float(v) for v in model.dist_coeffs))


def _render_pinhole(scene: Scene, pose: CameraPose, K: np.ndarray, size: tuple[int, int],
                    cell_size_m: float) -> np.ndarray:
    H = _homography(pose, K, cell_size_m)
    h, w = scene.free.shape
    cw, ch = size
    corners = np.array([[[0, 0]], [[cw - 1, 0]], [[0, ch - 1]], [[cw - 1, ch - 1]]], dtype=np.float64)
    # Landmarks in the ring lie up to one block outside the grid: the texture covers them too.
    pad = scene.landmarks.block_cells if scene.landmarks is not None and scene.landmarks.landmarks else 0
    H_inv = np.linalg.inv(H)
    if np.all((H_inv[2] @ np.vstack([corners.reshape(-1, 2).T, np.ones(4)])) > 0):
        floor = cv2.perspectiveTransform(corners, H_inv).reshape(-1, 2)
        fx0, fy0 = math.floor(floor[:, 0].min()), math.floor(floor[:, 1].min())
        fx1, fy1 = math.ceil(floor[:, 0].max()), math.ceil(floor[:, 1].max())
    else:   # a corner looks above the horizon: the whole floor may be in view
        fx0, fy0, fx1, fy1 = -pad, -pad, w + pad, h + pad
    x0, y0 = max(-pad, fx0 - 1), max(-pad, fy0 - 1)
    x1, y1 = min(w + pad, fx1 + 1), min(h + pad, fy1 + 1)
    if x0 >= x1 or y0 >= y1:
        outside = np.empty((ch, cw, 3), np.uint8)
        outside[:] = OUTSIDE_BGR
        return outside
    image_ppc = min(K[0, 0], K[1, 1]) * cell_size_m / -pose.down_m
    # A view of a huge floor from very high: keep the texture within OpenCV's comfort.
    ppc = max(1, min(_texture_ppc(image_ppc), MAX_TEXTURE_PX // max(x1 - x0, y1 - y0)))
    tex = _texture(scene, x0, y0, x1, y1, ppc, cell_size_m)
    # Texture pixel centre (i, j) is floor point (x0 + (i + 0.5)/ppc, y0 + (j + 0.5)/ppc) cells.
    tex_to_floor = np.array([[1 / ppc, 0, x0 + 0.5 / ppc], [0, 1 / ppc, y0 + 0.5 / ppc], [0, 0, 1]])
    return cv2.warpPerspective(tex, H @ tex_to_floor, (cw, ch), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=OUTSIDE_BGR)


def render(scene: Scene, pose: CameraPose | tuple, model: CameraModel, cell_size_m: float,
           seed: int | None = None, velocity_ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
           roi: Roi | None = None) -> np.ndarray:
    """The BGR uint8 image the camera sees from the TRUE `pose` (north, east, down[, yaw[, roll[,
    pitch]]]) while moving at `velocity_ned` m/s (motion blur over `model.exposure_ms`); only
    the sensor's region `roi` if given, the same pixels that region of the whole image has
    (but for the noise's draw), at its share of the cost."""
    p = as_pose(pose)
    x0, y0, w, h = roi if roi is not None else (0, 0, model.width, model.height)
    lens = lens_for(model)
    if lens is None:
        K = model.K.copy()
        K[0, 2] -= x0
        K[1, 2] -= y0
        image = _render_pinhole(scene, p, K, (w, h), cell_size_m)
    elif roi is None:
        wide = _render_pinhole(scene, p, lens.K, lens.size, cell_size_m)
        image = cv2.remap(wide, lens.map1, lens.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                          borderValue=OUTSIDE_BGR)
    else:
        map1, map2 = lens.map1[y0:y0 + h, x0:x0 + w], lens.map2[y0:y0 + h, x0:x0 + w]
        # The part of the pinhole canvas the region samples (map1 holds each pixel's whole source texel).
        lo = np.array([map1[..., 0].min(), map1[..., 1].min()], np.int64)
        hi = np.array([map1[..., 0].max(), map1[..., 1].max()], np.int64) + 2
        K = lens.K.copy()
        K[0, 2] -= lo[0]
        K[1, 2] -= lo[1]
        wide = _render_pinhole(scene, p, K, (int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)), cell_size_m)
        image = cv2.remap(wide, map1 - lo.astype(np.int16), map2, cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=OUTSIDE_BGR)
    return degrade(image, model, seed, _image_motion_px(p, model, velocity_ned), (x0, y0))


def _image_motion_px(pose: CameraPose, model: CameraModel, velocity_ned: tuple[float, float, float]
                     ) -> tuple[float, float]:
    """How far, in pixels (x, y), the floor under the optical axis moves during the exposure."""
    if model.exposure_ms <= 0 or not any(velocity_ned):
        return (0.0, 0.0)
    v_cam = camera_rotation(pose.yaw_rad, pose.roll_rad, pose.pitch_rad) @ np.asarray(velocity_ned, float)
    depth = -pose.down_m
    t = model.exposure_ms / 1000.0
    return (-model.fx * v_cam[0] / depth * t, -model.fy * v_cam[1] / depth * t)


def cell_centre_ned(cell: Cell, cell_size_m: float) -> tuple[float, float]:
    """(north, east) of a cell's centre: where to hover to look straight at it."""
    x, y = cell
    return -(y + 0.5) * cell_size_m, (x + 0.5) * cell_size_m


def scene_landmarks(free: np.ndarray, cell_size_m: float, spacing: int) -> LandmarkSet | None:
    """The surveyed landmarks the world places every `spacing` cells (None: 0, none)."""
    from scenarios.landmarks import place_landmarks
    return place_landmarks(free, cell_size_m, spacing) if spacing else None
