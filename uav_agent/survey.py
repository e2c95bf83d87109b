"""Hover poses from which a nadir camera sees every cell of the grid, sharp enough to read markers.

Geometry: at altitude h a nadir pinhole camera sees a floor rectangle of
(width_px / fx) * h by (height_px / fy) * h metres (yaw 0: image right = east)
at fx * c / h pixels per cell. The highest altitude that keeps
`min_px_per_cell` gives the widest footprint, hence the fewest frames; then the
camera comes down as far as it can while keeping that many frames, because a
lower view reads markers more reliably for free. Neighbouring footprints
overlap by at least one cell (plus a pixel border), so every cell lies wholly
inside at least one image.
"""
from __future__ import annotations

import functools
import math
from typing import NamedTuple, Protocol

from protocol.errors import MissionError


class CameraLike(Protocol):
    width: int
    height: int
    fx: float
    fy: float


def tilt_margin_px(model: CameraLike, tilt_rad: float) -> tuple[int, int]:
    """Pixels (x, y) by which a tilt of up to `tilt_rad` from the vertical (about any horizontal
    axis) may swing the floor a level camera would show out of the image at any edge.

    Not fx * tan(tilt): a ray leaving at angle a from the axis moves by f * (tan(a + tilt) -
    tan(a)), twice as far at a 45-degree edge as at the centre, and a roll also spreads or
    squeezes the image across (a corner moves both ways). The 450 survey's 1 degree, counted
    at the centre (35 px), left the wall's column of cells outside an edge image tilted away
    from it: a robot there went unseen and the mission flew a closer look for it."""
    cx = getattr(model, "cx", (model.width - 1) / 2)
    cy = getattr(model, "cy", (model.height - 1) / 2)
    return _tilt_margin(int(model.width), int(model.height), float(model.fx), float(model.fy), float(cx), float(cy),
                        float(tilt_rad))


@functools.lru_cache(maxsize=32)   # every arrival stop's region asks again, for the same camera
def _tilt_margin(width: int, height: int, fx: float, fy: float, cx: float, cy: float,
                 tilt_rad: float) -> tuple[int, int]:
    import numpy as np

    n = 64
    xs, ys = np.linspace(0, width - 1, n), np.linspace(0, height - 1, n)
    edge = np.concatenate([np.column_stack([np.zeros(n), ys]), np.column_stack([np.full(n, width - 1.0), ys]),
                           np.column_stack([xs, np.zeros(n)]), np.column_stack([xs, np.full(n, height - 1.0)])])
    rays = np.column_stack([(edge[:, 0] - cx) / fx, (edge[:, 1] - cy) / fy, np.ones(len(edge))])
    out = [0.0, 0.0]
    for phi in np.linspace(0.0, 2 * math.pi, 48, endpoint=False):
        # Rodrigues' rotation by tilt_rad about the horizontal axis (cos phi, sin phi, 0).
        k = np.array([[0.0, 0.0, math.sin(phi)], [0.0, 0.0, -math.cos(phi)], [-math.sin(phi), math.cos(phi), 0.0]])
        rot = np.eye(3) + math.sin(tilt_rad) * k + (1 - math.cos(tilt_rad)) * (k @ k)
        moved = rays @ rot.T
        u = moved[:, 0] / moved[:, 2] * fx + cx - edge[:, 0]
        v = moved[:, 1] / moved[:, 2] * fy + cy - edge[:, 1]
        # Outwards only: the left edge's points moving left, the top's up, and so on.
        out[0] = max(out[0], float(np.max(np.concatenate([-u[:n], u[n:2 * n]]))))
        out[1] = max(out[1], float(np.max(np.concatenate([-v[2 * n:3 * n], v[3 * n:]]))))
    return math.ceil(out[0]), math.ceil(out[1])


class SurveyPose(NamedTuple):
    north_m: float
    east_m: float
    alt_m: float     # above the floor (down = -alt_m), yaw 0


def _tiles(extent_m: float, usable_m: float, overlap_m: float) -> int:
    """How many footprints of `usable_m` overlapping by `overlap_m` cover `extent_m`."""
    if usable_m >= extent_m:
        return 1
    return math.ceil((extent_m - overlap_m) / (usable_m - overlap_m) - 1e-9)


def _centres(extent_m: float, usable_m: float, n: int) -> list[float]:
    """n footprint centres spread evenly: the first starts at 0, the last ends at extent."""
    if n == 1:
        return [extent_m / 2]
    stride = (extent_m - usable_m) / (n - 1)
    return [usable_m / 2 + i * stride for i in range(n)]


def heading_border(model: CameraLike, border_px: tuple[int, int], heading_rad: float) -> tuple[int, int]:
    """The border that leaves, of a footprint turned by `heading_rad` (an autopilot that ignores a
    goto's yaw: ArduCopter), the largest north-up rectangle of the same proportions centred in it:
    the survey's tiles are north-up, and a turned image must still hold its whole tile."""
    bx, by = border_px
    a, b = (model.width - 2 * bx) / model.fx, (model.height - 2 * by) / model.fy   # metres per metre up
    c, s = abs(math.cos(heading_rad)), abs(math.sin(heading_rad))
    k = min(1.0, a / (a * c + b * s), b / (a * s + b * c))
    # rounded up, but not for a rounding error's sake (facing south, sin(pi) is 1e-16)
    return (math.ceil((model.width - k * (model.width - 2 * bx)) / 2 - 1e-6),
            math.ceil((model.height - k * (model.height - 2 * by)) / 2 - 1e-6))


def survey_poses(width: int, height: int, cell_size_m: float, model: CameraLike, min_px_per_cell: float = 20.0,
                 max_alt_m: float = 120.0, min_alt_m: float = 3.0,
                 border_px: int | tuple[int, int] = 8) -> list[SurveyPose]:
    """Lawn-mower ordered hover poses (west to east, then back, moving south) covering a
    width x height grid; one pose when one image can hold the whole grid. `border_px`: pixels
    at each edge the survey does not count on, one number or (left and right, top and bottom)."""
    if width < 1 or height < 1:
        raise MissionError(f"survey: grid size {width}x{height} is not positive")
    if not cell_size_m > 0:
        raise MissionError(f"survey: cell size must be positive, got {cell_size_m}")
    if not 0 < min_alt_m <= max_alt_m:
        raise MissionError(f"survey: need 0 < min_alt_m <= max_alt_m, got {min_alt_m} and {max_alt_m}")
    bx, by = (border_px, border_px) if isinstance(border_px, int) else border_px
    usable_w, usable_h = model.width - 2 * bx, model.height - 2 * by
    if usable_w < 1 or usable_h < 1 or min_px_per_cell <= 0:
        raise MissionError(f"survey: a {model.width}x{model.height} image with a {bx} x {by} px border "
                           f"cannot show cells at {min_px_per_cell} px")
    # A footprint must also span more than one cell plus the overlap, or tiles never advance.
    alt = min(max_alt_m, min(model.fx, model.fy) * cell_size_m / min_px_per_cell)
    if alt < min_alt_m:
        raise MissionError(f"survey: {min_px_per_cell} px per {cell_size_m} m cell needs flying below "
                           f"{alt:.2f} m, under the minimum altitude {min_alt_m} m")
    span_x, span_y = usable_w / model.fx, usable_h / model.fy   # footprint metres per metre of altitude
    if min(span_x, span_y) * alt <= 2 * cell_size_m:
        raise MissionError(f"survey: at {alt:.1f} m an image spans under two {cell_size_m} m cells; "
                           "raise max_alt_m or lower min_px_per_cell")
    ext_x, ext_y = width * cell_size_m, height * cell_size_m
    nx = _tiles(ext_x, span_x * alt, cell_size_m)
    ny = _tiles(ext_y, span_y * alt, cell_size_m)
    # Lowest altitude at which nx x ny tiles still cover: n*U - (n-1)*c >= extent.
    need = max((ext_x + (nx - 1) * cell_size_m) / nx / span_x, (ext_y + (ny - 1) * cell_size_m) / ny / span_y)
    alt = min(alt, max(min_alt_m, need * (1 + 1e-6)))
    easts = _centres(ext_x, span_x * alt, nx)
    souths = _centres(ext_y, span_y * alt, ny)
    # Footprints are centred on the principal point, not the image centre, if the two differ.
    cx = getattr(model, "cx", (model.width - 1) / 2)
    cy = getattr(model, "cy", (model.height - 1) / 2)
    de = ((model.width - 1) / 2 - cx) / model.fx * alt
    dn = -((model.height - 1) / 2 - cy) / model.fy * alt
    rows = [SurveyPose(-south - dn, east - de, alt)
            for row, south in enumerate(souths) for east in (easts if row % 2 == 0 else easts[::-1])]
    columns = [SurveyPose(-south - dn, east - de, alt)
               for col, east in enumerate(easts) for south in (souths if col % 2 == 0 else souths[::-1])]
    # Along the floor's longer side of footprints: fewer, longer legs (the vehicle starts at home, 0/0).
    return min(rows, columns, key=lambda poses: path_length(poses, (0.0, 0.0)))


def path_length(poses, start: tuple[float, float]) -> float:
    """Horizontal metres flown from `start` through `poses` in order."""
    points = [start, *((p[0], p[1]) for p in poses)]
    return sum(math.dist(a, b) for a, b in zip(points, points[1:]))


def nearest_pose(poses, cell, cell_size_m: float) -> int:
    """The index of the pose nearest the centre of `cell` (x, y)."""
    north, east = -(cell[1] + 0.5) * cell_size_m, (cell[0] + 0.5) * cell_size_m
    return min(range(len(poses)), key=lambda i: math.hypot(poses[i][0] - north, poses[i][1] - east))


def covering(poses: list[SurveyPose], cells, cell_size_m: float) -> list[SurveyPose]:
    """The survey poses, in survey order, whose images hold `cells` (x, y): each cell's nearest
    pose. Footprints of one survey overlap by a cell, so a cell lies wholly inside its nearest one."""
    if not poses:
        return []
    wanted = {nearest_pose(poses, cell, cell_size_m) for cell in cells}
    return [p for i, p in enumerate(poses) if i in wanted]


def nearer_end_first(poses: list[SurveyPose], here: tuple[float, float]) -> list[SurveyPose]:
    """`poses` in their order or reversed, whichever starts nearer `here` (north, east)."""
    if len(poses) > 1 and math.dist(here, poses[-1][:2]) < math.dist(here, poses[0][:2]):
        return poses[::-1]
    return poses


ROBOT_MODULE_CELLS = 1 / 8      # a robot marker's module: the cell is 8 modules wide
SHARP_SIGMA_PX = 1.1            # measured blur of a sharp camera's image (lens resampling, JPEG): 0.6..1.05
# The resolution the blur law starts from, as measured (blur 2 at 5 % less left one robot of 50 unread
# after three closer looks): a sharp image needs less (the mission's 19 px per cell), a blurred one this.
BLUR_LAW_PX = 20.0


def px_per_cell_for(blur_px: float, min_px_per_cell: float, module_cells: float = ROBOT_MODULE_CELLS) -> float:
    """Resolution the survey needs for markers to read through a measured blur of `blur_px`.

    A sharp image keeps `min_px_per_cell`. Past that, the resolution grows from
    BLUR_LAW_PX with the square of the blur (the estimate runs low as blur grows: measured
    1.8 for a true 2, 2.3 for a true 3), and with how much smaller than a robot's a
    landmark's module is."""
    if not math.isfinite(blur_px) or blur_px <= SHARP_SIGMA_PX:
        return min_px_per_cell
    return max(min_px_per_cell,
               BLUR_LAW_PX * (blur_px / SHARP_SIGMA_PX) ** 2 * max(1.0, ROBOT_MODULE_CELLS / module_cells))
