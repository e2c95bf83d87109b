"""Robots by their ArUco marker (DICT_4X4_1000, id = robot id).

Markers are found by the detector in a small window of the (undistorted) image
around each cell that shows a marker's contrast (a robot stands on one cell, and
a 12 MP frame holds a few dozen of them in a sea of shelves and floor), the
marker centre through the view's homography to a floor point, hence a cell;
then every marker-like cell is also read in place (resampled onto its module grid by the
homography): that read rescues small, blurred or noisy markers whose outline
the detector misses, and vetoes a detector read its modules contradict. Both
need the registration to be right, which the landmarks give.
"""
from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Collection
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from protocol.grid import Cell, on_grid

from .view import View, to_floor, to_image

ARUCO_DICTIONARY = cv2.aruco.DICT_4X4_1000
_DICTIONARY = cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY)
CELL_UNITS = 8                 # the world's marker layout: a robot cell is 8 modules wide,
MARKER_SIZE_CELLS = 0.75       # a 6-module marker inside a 1-module white quiet zone
MARKER_BITS = 4                # 4x4 data bits inside the marker's black frame
MARKER_UNITS = 6               # the marker's side in modules (data + black frame)
PAD_MARKER_CELLS = 0.8 * 6 / 7  # a robot body of 0.8 cell holding its marker with half a module of white
DECODE_MODULE_PX = 6           # resampling of a marker module for the in-place read
DECODE_MIN_CONFIDENCE = 0.04   # of the black-white contrast: the weakest module's margin
DETECTOR_MAX_CONTRADICTION = 0.25  # measured: true reads >= -0.18, misreads <= -0.30
FAINT_MIN_SUPPORT = -0.2       # a faint read names a robot not seen elsewhere if no module contradicts it more ...
FAINT_MIN_GAP = 0.25           # ... and it fits that robot this much better than any other such robot
MIN_MARKER_CONTRAST = 0.3      # (white - black) / white of a readable marker
WINDOW_CELLS = 1.0             # half the side of a detector window: the cell and half of each neighbour
WINDOW_PAD_PX = 4              # and a few pixels more, for the pose's error and the detector's border margin


@lru_cache(maxsize=16)
def _detector(marker_perimeter_rate: float) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    # The altitude fixes a marker's size in pixels: candidates far off it are
    # shelves or noise, and skipping them makes detection several times faster.
    params.minMarkerPerimeterRate = 0.6 * marker_perimeter_rate
    params.maxMarkerPerimeterRate = 1.6 * marker_perimeter_rate
    # Sample bits on a finer grid and away from module edges: survey markers are ~15 px.
    params.perspectiveRemovePixelPerCell = 8
    params.perspectiveRemoveIgnoredMarginPerCell = 0.3
    # A marker's inside is black and white; a plain shelf or floor square is not worth decoding
    # (each decode searches the whole dictionary: thousands of shelf squares cost seconds).
    params.minOtsuStdDev = MIN_CANDIDATE_STD
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    return cv2.aruco.ArucoDetector(_DICTIONARY, params)

MIN_CANDIDATE_STD = 15.0   # grey std inside a marker candidate (a marker's is ~100, a blank square's noise < 10)


@dataclass(frozen=True)
class Sighting:
    robot: int
    cell: Cell
    quality: float     # marker perimeter in pixels, discounted near the image edge or for in-place reads


def _sighting(view: View, quad: np.ndarray, rid: int, grid: tuple[int, int], warnings: list[str]
              ) -> Sighting | None:
    floor = to_floor(quad, view.H_inv)
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
    return Sighting(rid, cell, perimeter * min(1.0, 0.5 + edge / 100.0))


_RING = np.zeros((CELL_UNITS, CELL_UNITS), bool)
_RING[[0, -1], :] = _RING[:, [0, -1]] = True                   # white quiet zone
_BORDER = np.zeros((CELL_UNITS, CELL_UNITS), bool)
_BORDER[1:-1, 1:-1] = True
_BORDER[2:-2, 2:-2] = False                                    # the marker's black frame


def _module_margins(view: View, cell: Cell, marker_cells: float = MARKER_SIZE_CELLS) -> np.ndarray | None:
    """The 4x4 data modules of the marker in `cell`, read where the geometry says they are.

    The homography is known, so the cell is resampled onto its 8x8 module grid
    and each module read at its centre, with the white quiet zone and the black
    frame as references. Returns each module's brightness minus the black-white
    midpoint, as a fraction of the contrast (> 0: a white bit), or None when the
    cell does not show a marker's frame. This needs no contour of the marker,
    which is what fails first on small, blurred, noisy markers."""
    q = DECODE_MODULE_PX
    x, y = cell
    # An 8x8 module grid centred on the cell: the marker's 6 modules and one ring outside them.
    step = marker_cells / MARKER_UNITS / q                     # cells per resampled pixel
    start = 0.5 - CELL_UNITS / 2 * q * step + step / 2
    to_floor = np.array([[step, 0, x + start], [0, step, y + start], [0, 0, 1]])
    patch = cv2.warpPerspective(view.gray, view.H @ to_floor, (CELL_UNITS * q, CELL_UNITS * q),
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    modules = patch.reshape(CELL_UNITS, q, CELL_UNITS, q)[:, q // 3: q - q // 3, :, q // 3: q - q // 3]
    modules = modules.astype(np.float32).mean(axis=(1, 3))
    white, black = float(np.median(modules[_RING])), float(np.median(modules[_BORDER]))
    # Relative contrast: the same marker under half the light is still a marker.
    if white - black < MIN_MARKER_CONTRAST * white:
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


def _detect_near(view: View, cells: Collection[Cell], perimeter: float) -> list[tuple[np.ndarray, int]]:
    """ArUco detections (image corners, id) in a window around each of `cells`.

    Every window has the same size, so one detector (its perimeter limits are
    relative to the image's side) serves them all."""
    img_h, img_w = view.gray.shape
    side = min(2 * (math.ceil(WINDOW_CELLS * view.ppc) + WINDOW_PAD_PX), img_w, img_h)
    if not cells:
        return []
    detector = _detector(round(perimeter / side, 4))
    found: list[tuple[np.ndarray, int]] = []
    for cx, cy in to_image([(x + 0.5, y + 0.5) for x, y in sorted(cells)], view.H):
        if not (np.isfinite(cx) and np.isfinite(cy)):
            continue
        x0 = min(max(0, round(cx) - side // 2), img_w - side)
        y0 = min(max(0, round(cy) - side // 2), img_h - side)
        corners, ids, _ = detector.detectMarkers(view.gray[y0:y0 + side, x0:x0 + side])
        for quad, rid in zip(corners, [] if ids is None else ids.ravel().tolist()):
            found.append((quad.reshape(4, 2).astype(np.float64) + (x0, y0), rid))
    return found


def read_markers(view: View, candidates: set[Cell], grid: tuple[int, int], warnings: list[str],
                 near: Collection[Cell] | None = None, faint: list | None = None) -> list[Sighting]:
    """ArUco detection around the cells `near` (default the candidates), checked against, and
    completed by, an in-place read of every marker-like cell (the candidates). A cell whose
    modules show a marker but name no code clearly goes to `faint` as (cell, [module margins
    of each grid that read a frame]) for `read_faint`; so does every cell `near` but not a
    candidate that the detector did not read (a marker dimmed under the candidates' contrast
    by the lighting, at an image's edge), however clearly its modules read."""
    perimeter = 4 * MARKER_SIZE_CELLS * view.ppc
    by_cell: dict[Cell, Sighting] = {}
    for quad, rid in _detect_near(view, candidates if near is None else near, perimeter):
        s = _sighting(view, quad, rid, grid, warnings)
        if s is not None:
            by_cell[s.cell] = s
    in_place_quality = perimeter * 0.8   # it trusts the pose, not the marker's own corners
    dim = set() if faint is None or near is None else set(near) - candidates - set(by_cell)
    for cell in sorted(candidates | set(by_cell) | dim):
        margins = full = _module_margins(view, cell)
        pad = None
        if margins is None or _identify(margins)[1] < DECODE_MIN_CONFIDENCE:   # names no code clearly
            # The pad layout's smaller marker on a white body (sim_world.camera, goal_pads).
            pad = _module_margins(view, cell, PAD_MARKER_CELLS)
            # Where the detector read the cell, the pad grid's read checks it only if it names a
            # code clearly: the full-cell grid laid over a pad marker reads its modules half off
            # and would veto a true detection, but a noisy full-cell marker read with the pad
            # grid names nothing clearly and must not let a misread through.
            if pad is not None and (margins is None or by_cell.get(cell) is None
                                    or _identify(pad)[1] >= DECODE_MIN_CONFIDENCE):
                margins = pad
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
            if rid is not None and confidence >= DECODE_MIN_CONFIDENCE and cell not in dim:
                by_cell[cell] = Sighting(rid, cell, in_place_quality)
            elif faint is not None:
                faint.append((cell, [m for m in (full, pad) if m is not None]))
    return list(by_cell.values())


def read_faint(faint: list, cells: Collection[Cell], known: Collection[int], seen: Collection[int],
               warnings: list[str]) -> dict[int, Cell]:
    """Markers whose modules no view read clearly, decoded against the codebook of the robots known
    to exist (at 19 px per cell an image corner's lens and vignetting leave a white module just
    under the clear-read margin). A cell names robot r, one not `seen` elsewhere, when some read
    fits r with no module contradicting it by more than FAINT_MIN_SUPPORT and fits every other
    known robot worse by FAINT_MIN_GAP; one robot per cell and one cell per robot."""
    unseen = set(known) - set(seen)
    if not unseen:
        return {}
    best: dict[Cell, tuple[float, int, float]] = {}    # cell -> (support, robot, next best)
    for cell, reads in faint:
        if cell not in cells:
            continue
        for margins in reads:
            fits = sorted(((_support(margins, r), r) for r in known), reverse=True)
            top, rid = fits[0]
            runner = fits[1][0] if len(fits) > 1 else -1.0
            if (rid in unseen and top >= FAINT_MIN_SUPPORT and top - runner >= FAINT_MIN_GAP
                    and top > best.get(cell, (-9.0,))[0]):
                best[cell] = (top, rid, runner)
    found: dict[int, Cell] = {}
    for cell, (top, rid, runner) in sorted(best.items(), key=lambda kv: -kv[1][0]):
        if rid not in found:
            found[rid] = cell
            warnings.append(f"marker {rid} at {cell} read faintly against the {len(known)} known robots "
                            f"(fit {top:+.2f}, next best {runner:+.2f})")
    return found



def settle(sightings: list[Sighting], known_ids: Collection[int] | None, warnings: list[str]) -> dict[int, Cell]:
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
