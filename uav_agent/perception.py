"""Camera frames -> world model: occupancy grid, robots by marker id, goal cells.

Uses only the images, their `CameraFrame` metadata (intrinsics and camera pose
in the local NED frame whose origin is the grid's top-left corner) and the
grid's size: never the world's ground truth. The camera looks straight down, so
the floor plane maps to each image by a homography H (floor cells -> pixels):
- occupancy: each frame is warped back onto the grid (an orthophoto at a few
  pixels per cell); a cell's central patch is floor if bright, shelf if dark,
  and a cell of high contrast (black marker on white) is a robot candidate;
- robots: ArUco markers (DICT_4X4_1000, id = robot id) found in the whole
  image, the marker centre through H^-1 to a floor point, hence a cell; then
  every robot candidate is also read in place (resampled onto its module grid
  by H): that read rescues small, blurred or noisy markers whose outline the
  detector misses, and vetoes a detector read its modules contradict;
- goals: saturated green blobs (HSV threshold + connected components), their
  centroids through H^-1.
A cell counts as seen when it lies wholly inside an image. Frames are merged by
majority vote per cell (ties go to the sharpest view); an id read at two cells,
or two ids read at one cell, is settled by the summed quality of the readings
and reported in `warnings`.
"""
from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Collection
from dataclasses import dataclass, field
from functools import lru_cache

import cv2
import numpy as np

from protocol.errors import MissionError, ProtocolError
from protocol.grid import Cell, on_grid
from protocol.messages import CameraFrame

ARUCO_DICTIONARY = cv2.aruco.DICT_4X4_1000
_DICTIONARY = cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY)
CELL_UNITS = 8                 # the world's marker layout: a robot cell is 8 modules wide,
MARKER_SIZE_CELLS = 0.75       # a 6-module marker inside a 1-module white quiet zone
MARKER_BITS = 4                # 4x4 data bits inside the marker's black frame
SHELF_LUMA_MAX = 110.0         # floor ~215 grey, shelves ~65: split well below a dimmed floor
MARKER_STD_MIN = 35.0          # grey std over a cell: marker 45..130, goal <= 30, floor/shelf <= 15
GOAL_HSV_LO = (45, 110, 110)   # saturated, bright green; the goal's dark ring stays out
GOAL_HSV_HI = (75, 255, 255)
GOAL_AREA_CELLS = (0.15, 0.9)  # a disc of radius ~0.35 cell: ~0.38 cell^2
ORTHO_PPC = 8                  # orthophoto pixels per cell
BORDER_PX = 2                  # a cell this close to the image edge is not trusted
DECODE_MODULE_PX = 6           # resampling of a marker module for the in-place read
DECODE_MIN_CONFIDENCE = 0.04   # of the black-white contrast: the weakest module's margin
DETECTOR_MAX_CONTRADICTION = 0.25  # measured: true reads >= -0.18, misreads <= -0.30


@dataclass(frozen=True, eq=False)
class Frame:
    image: np.ndarray      # BGR uint8, height x width
    meta: CameraFrame      # its pose and intrinsics; meta.png is not read (may be empty)


@dataclass(eq=False)
class WorldModel:
    free: np.ndarray                   # bool [height, width]; unseen cells are False
    robots: dict[int, Cell]            # marker id -> cell
    goals: list[Cell]
    seen: np.ndarray                   # bool [height, width]: wholly inside at least one image
    unseen: int                        # cells no image covers
    unidentified: list[Cell] = field(default_factory=list)  # a marker is there, its id unread
    warnings: list[str] = field(default_factory=list)


def decode_frame(msg: CameraFrame) -> Frame:
    """CameraFrame (PNG bytes) -> Frame; ProtocolError if the image is not what it claims."""
    image = cv2.imdecode(np.frombuffer(msg.png, np.uint8), cv2.IMREAD_COLOR) if msg.png else None
    if image is None:
        raise ProtocolError(f"CameraFrame: {len(msg.png)} bytes of png do not decode to an image")
    if image.shape[:2] != (msg.height, msg.width):
        raise ProtocolError(f"CameraFrame: image is {image.shape[1]}x{image.shape[0]}, "
                            f"header says {msg.width}x{msg.height}")
    return Frame(image=image, meta=msg)


def homography(meta: CameraFrame, cell_size_m: float) -> np.ndarray:
    """Floor coordinates in cells (u = east/c, v = -north/c) -> pixel, for a nadir camera.

    Camera axes in NED for heading psi: image right = (-sin, cos, 0), image down =
    (-cos, -sin, 0), optical axis = (0, 0, 1); floor point (u, v) is NED (-v c, u c, 0)."""
    numbers = (meta.fx, meta.fy, meta.cx, meta.cy, meta.north_m, meta.east_m, meta.down_m, meta.yaw_rad)
    if not all(math.isfinite(v) for v in numbers) or meta.fx <= 0 or meta.fy <= 0:
        raise ProtocolError(f"frame at t={meta.time_s:.2f}s: pose or intrinsics are not finite, positive numbers")
    if not meta.down_m < 0:
        raise MissionError(f"frame at t={meta.time_s:.2f}s: camera down={meta.down_m} m is not above the floor")
    s, co, c = math.sin(meta.yaw_rad), math.cos(meta.yaw_rad), cell_size_m
    n, e, alt = meta.north_m, meta.east_m, -meta.down_m
    cam = np.array([[co * c, s * c, s * n - co * e],
                    [-s * c, co * c, co * n + s * e],
                    [0.0, 0.0, alt]])
    K = np.array([[meta.fx, 0.0, meta.cx], [0.0, meta.fy, meta.cy], [0.0, 0.0, 1.0]])
    return K @ cam


def _to_floor(points_px, H_inv: np.ndarray) -> np.ndarray:
    return cv2.perspectiveTransform(np.asarray(points_px, np.float64).reshape(-1, 1, 2), H_inv).reshape(-1, 2)


def _px_per_cell(H: np.ndarray) -> float:
    """Image pixels per cell side; exact for a nadir camera, where H is affine."""
    return float(math.sqrt(abs(np.linalg.det(H[:2, :2]))) / abs(H[2, 2]))


def _detector(marker_perimeter_rate: float) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    # The altitude fixes a marker's size in pixels: candidates far off it are
    # shelves or noise, and skipping them makes detection several times faster.
    params.minMarkerPerimeterRate = 0.6 * marker_perimeter_rate
    params.maxMarkerPerimeterRate = 1.6 * marker_perimeter_rate
    # Sample bits on a finer grid and away from module edges: survey markers are ~15 px.
    params.perspectiveRemovePixelPerCell = 8
    params.perspectiveRemoveIgnoredMarginPerCell = 0.3
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(_DICTIONARY, params)


@dataclass(frozen=True)
class _Sighting:
    robot: int
    cell: Cell
    quality: float     # marker perimeter in pixels, discounted near the image edge or for in-place reads


@dataclass
class _View:
    """One frame, prepared: its homography both ways and its grey image."""
    frame: Frame
    H: np.ndarray
    H_inv: np.ndarray
    gray: np.ndarray
    ppc: float


def _sighting(view: _View, quad: np.ndarray, rid: int, grid: tuple[int, int], warnings: list[str]
              ) -> _Sighting | None:
    floor = _to_floor(quad, view.H_inv)
    side = float(np.mean(np.linalg.norm(floor - np.roll(floor, 1, axis=0), axis=1)))
    centre = floor.mean(axis=0)
    cell = (math.floor(centre[0]), math.floor(centre[1]))
    offset = float(np.abs(centre - np.array(cell) - 0.5).max())
    # A true marker is 0.75 cell wide and centred in its cell; anything else is a misread.
    if not (0.6 * MARKER_SIZE_CELLS < side < 1.4 * MARKER_SIZE_CELLS) or offset > 0.25:
        warnings.append(f"ignored marker {rid} at {cell}: {side:.2f} cell wide, {offset:.2f} cell off centre")
        return None
    if not on_grid(*cell, *grid):
        warnings.append(f"ignored marker {rid} seen off the grid at {cell}")
        return None
    img_h, img_w = view.gray.shape
    edge = min(quad[:, 0].min(), quad[:, 1].min(), img_w - 1 - quad[:, 0].max(), img_h - 1 - quad[:, 1].max())
    perimeter = float(cv2.arcLength(quad.astype(np.float32), True))
    return _Sighting(rid, cell, perimeter * min(1.0, 0.5 + edge / 100.0))


_RING = np.zeros((CELL_UNITS, CELL_UNITS), bool)
_RING[[0, -1], :] = _RING[:, [0, -1]] = True                   # white quiet zone
_BORDER = np.zeros((CELL_UNITS, CELL_UNITS), bool)
_BORDER[1:-1, 1:-1] = True
_BORDER[2:-2, 2:-2] = False                                    # the marker's black frame


def _module_margins(view: _View, cell: Cell) -> np.ndarray | None:
    """The 4x4 data modules of the marker in `cell`, read where the geometry says they are.

    The homography is known, so the cell is resampled onto its 8x8 module grid
    and each module read at its centre, with the white quiet zone and the black
    frame as references. Returns each module's brightness minus the black-white
    midpoint, as a fraction of the contrast (> 0: a white bit), or None when the
    cell does not show a marker's frame. This needs no contour of the marker,
    which is what fails first on small, blurred, noisy markers."""
    q = DECODE_MODULE_PX
    x, y = cell
    to_floor = np.array([[1 / (CELL_UNITS * q), 0, x + 0.5 / (CELL_UNITS * q)],
                         [0, 1 / (CELL_UNITS * q), y + 0.5 / (CELL_UNITS * q)], [0, 0, 1]])
    patch = cv2.warpPerspective(view.gray, view.H @ to_floor, (CELL_UNITS * q, CELL_UNITS * q),
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    modules = patch.reshape(CELL_UNITS, q, CELL_UNITS, q)[:, q // 3: q - q // 3, :, q // 3: q - q // 3]
    modules = modules.astype(np.float32).mean(axis=(1, 3))
    white, black = float(np.median(modules[_RING])), float(np.median(modules[_BORDER]))
    if white - black < 40:
        return None
    threshold = (white + black) / 2
    if (modules[_RING] < threshold).sum() > 2 or (modules[_BORDER] > threshold).sum() > 2:
        return None
    return (modules[2:-2, 2:-2] - threshold) / (white - black)


def _identify(margins: np.ndarray) -> tuple[int | None, float]:
    """(id or None, confidence = the weakest module's margin)."""
    found, rid, _ = _DICTIONARY.identify((margins > 0).astype(np.uint8), 0.0)
    return (int(rid), float(np.abs(margins).min())) if found else (None, 0.0)


@lru_cache(maxsize=1024)
def _code(rid: int) -> tuple[np.ndarray, ...]:
    """A marker's data bits as +1 (white) / -1 (black), in its four rotations."""
    bits = cv2.aruco.Dictionary.getBitsFromByteList(_DICTIONARY.bytesList[rid:rid + 1], MARKER_BITS)
    signs = 2.0 * bits.astype(np.float32) - 1.0
    return tuple(np.rot90(signs, k) for k in range(4))


def _support(margins: np.ndarray, rid: int) -> float:
    """How well the modules fit marker `rid`: the worst module's signed margin (< 0: contradicts)."""
    return max(float((margins * signs).min()) for signs in _code(rid))


def _read_markers(view: _View, candidates: set[Cell], grid: tuple[int, int], warnings: list[str]
                  ) -> list[_Sighting]:
    """ArUco detection over the whole image, checked against, and completed by, an
    in-place read of every marker-like cell."""
    img_h, img_w = view.gray.shape
    perimeter = 4 * MARKER_SIZE_CELLS * view.ppc
    corners, ids, _ = _detector(perimeter / max(img_w, img_h)).detectMarkers(view.gray)
    by_cell: dict[Cell, _Sighting] = {}
    for quad, rid in zip(corners, [] if ids is None else ids.ravel().tolist()):
        s = _sighting(view, quad.reshape(4, 2).astype(np.float64), rid, grid, warnings)
        if s is not None:
            by_cell[s.cell] = s
    in_place_quality = perimeter * 0.8   # it trusts the pose, not the marker's own corners
    for cell in sorted(candidates | set(by_cell)):
        margins = _module_margins(view, cell)
        if margins is None:
            continue   # no clean frame where the pose puts it: a detector read stands alone
        detected = by_cell.get(cell)
        # Detector misreads (corners misplaced on a small marker) leave modules that
        # contradict the claimed code; true reads never do by this much.
        if detected is not None and _support(margins, detected.robot) < -DETECTOR_MAX_CONTRADICTION:
            warnings.append(f"dropped marker {detected.robot} at {cell}: its modules read otherwise")
            del by_cell[cell]
            detected = None
        if detected is None:
            rid, confidence = _identify(margins)
            if rid is not None and confidence >= DECODE_MIN_CONFIDENCE:
                by_cell[cell] = _Sighting(rid, cell, in_place_quality)
    return list(by_cell.values())


def _goals_in(view: _View, grid: tuple[int, int]) -> set[Cell]:
    hsv = cv2.cvtColor(view.frame.image, cv2.COLOR_BGR2HSV)
    mask = cv2.inRange(hsv, GOAL_HSV_LO, GOAL_HSV_HI)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    count, _, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    img_h, img_w = mask.shape
    goals: set[Cell] = set()
    for i in range(1, count):
        x, y, bw, bh, area = stats[i]
        if x <= BORDER_PX or y <= BORDER_PX or x + bw >= img_w - BORDER_PX or y + bh >= img_h - BORDER_PX:
            continue  # cut by the image edge, so its centroid lies; a neighbouring frame sees it whole
        if not GOAL_AREA_CELLS[0] <= area / view.ppc ** 2 <= GOAL_AREA_CELLS[1]:
            continue
        u, v = _to_floor(centroids[i], view.H_inv)[0]
        cell = (math.floor(u), math.floor(v))
        if on_grid(*cell, *grid):
            goals.add(cell)
    return goals


@dataclass
class _Cells:
    """Per-cell readings of one frame over the box [x0, x0+w) x [y0, y0+h) of the grid."""
    x0: int
    y0: int
    seen: np.ndarray
    free: np.ndarray
    marker_like: np.ndarray


def _cells_in(view: _View, grid: tuple[int, int]) -> _Cells | None:
    img_h, img_w = view.gray.shape
    corners = _to_floor([[0, 0], [img_w - 1, 0], [0, img_h - 1], [img_w - 1, img_h - 1]], view.H_inv)
    x0, y0 = max(0, math.floor(corners[:, 0].min())), max(0, math.floor(corners[:, 1].min()))
    x1, y1 = min(grid[0], math.ceil(corners[:, 0].max())), min(grid[1], math.ceil(corners[:, 1].max()))
    if x0 >= x1 or y0 >= y1:
        return None
    # A cell is seen if its four corners project inside the image, away from the edge.
    gx, gy = np.meshgrid(np.arange(x0, x1 + 1, dtype=np.float64), np.arange(y0, y1 + 1, dtype=np.float64))
    px = cv2.perspectiveTransform(np.stack([gx, gy], -1).reshape(-1, 1, 2), view.H)
    px = px.reshape(y1 - y0 + 1, x1 - x0 + 1, 2)
    inside = ((px[..., 0] >= BORDER_PX) & (px[..., 0] <= img_w - 1 - BORDER_PX)
              & (px[..., 1] >= BORDER_PX) & (px[..., 1] <= img_h - 1 - BORDER_PX))
    seen = inside[:-1, :-1] & inside[1:, :-1] & inside[:-1, 1:] & inside[1:, 1:]
    if not seen.any():
        return None
    q, nx, ny = ORTHO_PPC, x1 - x0, y1 - y0
    ortho_to_floor = np.array([[1 / q, 0, x0 + 0.5 / q], [0, 1 / q, y0 + 0.5 / q], [0, 0, 1]])
    ortho = cv2.warpPerspective(view.gray, view.H @ ortho_to_floor, (nx * q, ny * q),
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    cells = ortho.reshape(ny, q, nx, q).astype(np.float32)
    # Brightness from the central half only: the warp blurs cell edges into neighbours.
    luma = cells[:, q // 4: q - q // 4, :, q // 4: q - q // 4].mean(axis=(1, 3))
    return _Cells(x0, y0, seen, luma > SHELF_LUMA_MAX, seen & (cells.std(axis=(1, 3)) > MARKER_STD_MIN))


def _settle(sightings: list[_Sighting], known_ids: Collection[int] | None, warnings: list[str]) -> dict[int, Cell]:
    """One cell per id and one id per cell, by summed quality of the readings."""
    score: dict[tuple[int, Cell], float] = defaultdict(float)
    for s in sightings:
        if known_ids is not None and s.robot not in known_ids:
            warnings.append(f"ignored marker {s.robot} at {s.cell}: not a known robot id")
            continue
        score[(s.robot, s.cell)] += s.quality
    robots: dict[int, Cell] = {}
    taken: dict[Cell, int] = {}
    for (rid, cell), _ in sorted(score.items(), key=lambda kv: -kv[1]):
        if rid in robots:
            warnings.append(f"marker {rid} read at {robots[rid]} and at {cell}: kept {robots[rid]}, the clearer")
        elif cell in taken:
            warnings.append(f"cell {cell} read as marker {taken[cell]} and as {rid}: kept {taken[cell]}, the clearer")
        else:
            robots[rid] = cell
            taken[cell] = rid
    return dict(sorted(robots.items()))


def perceive(frames: list[Frame | CameraFrame], width: int, height: int, cell_size_m: float,
             known_ids: Collection[int] | None = None) -> WorldModel:
    """Merge overhead frames into a world model of a width x height grid.

    `known_ids` (the fleet's robot ids, if the caller knows them from the
    network) turns a marker read as any other id into a warning, not a robot."""
    if width < 1 or height < 1:
        raise MissionError(f"perception: grid size {width}x{height} is not positive")
    if not cell_size_m > 0:
        raise MissionError(f"perception: cell size must be positive, got {cell_size_m}")
    grid = (width, height)
    votes_free = np.zeros((height, width), np.int32)
    votes_shelf = np.zeros((height, width), np.int32)
    best_ppc = np.zeros((height, width))
    best_free = np.zeros((height, width), bool)
    marker_like = np.zeros((height, width), bool)
    sightings: list[_Sighting] = []
    goals: set[Cell] = set()
    warnings: list[str] = []
    for item in frames:
        frame = decode_frame(item) if isinstance(item, CameraFrame) else item
        if frame.image.ndim != 3 or frame.image.shape[:2] != (frame.meta.height, frame.meta.width):
            raise ProtocolError(f"frame at t={frame.meta.time_s:.2f}s: image shape {frame.image.shape} "
                                f"does not match its {frame.meta.width}x{frame.meta.height} header")
        H = homography(frame.meta, cell_size_m)
        view = _View(frame, H, np.linalg.inv(H), cv2.cvtColor(frame.image, cv2.COLOR_BGR2GRAY), _px_per_cell(H))
        cells = _cells_in(view, grid)
        if cells is None:
            continue
        sl = (slice(cells.y0, cells.y0 + cells.seen.shape[0]), slice(cells.x0, cells.x0 + cells.seen.shape[1]))
        votes_free[sl] += cells.seen & cells.free
        votes_shelf[sl] += cells.seen & ~cells.free
        better = cells.seen & (view.ppc > best_ppc[sl])
        best_ppc[sl] = np.where(better, view.ppc, best_ppc[sl])
        best_free[sl] = np.where(better, cells.free, best_free[sl])
        frame_goals = _goals_in(view, grid)
        goals |= frame_goals
        ys, xs = np.nonzero(cells.marker_like)
        candidates = {(int(x) + cells.x0, int(y) + cells.y0) for x, y in zip(xs, ys)} - frame_goals
        for x, y in candidates:
            marker_like[y, x] = True
        sightings += _read_markers(view, candidates, grid, warnings)
    seen = (votes_free + votes_shelf) > 0
    free = np.where(votes_free == votes_shelf, best_free, votes_free > votes_shelf) & seen
    robots = _settle(sightings, known_ids, warnings)
    robot_cells = set(robots.values())
    marked = {(int(x), int(y)) for y, x in zip(*np.nonzero(marker_like))}
    unidentified = sorted(marked - robot_cells - goals)
    for x, y in list(robot_cells) + list(goals) + unidentified:
        free[y, x] = seen[y, x] = True   # floor under a robot or a goal marker
    if unidentified:
        warnings.append(f"{len(unidentified)} marker(s) seen but not read, at {unidentified[:5]}")
    return WorldModel(free=free, robots=robots, goals=sorted(goals), seen=seen,
                      unseen=int(width * height - seen.sum()), unidentified=unidentified, warnings=warnings)
