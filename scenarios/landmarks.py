"""Surveyed fiducials: ArUco markers at known floor positions, for registering images.

A real site is surveyed once: markers are fixed where nothing drives over them
and their positions are measured. Here they sit on SHELF cells (tops of
obstacles), so no robot or goal ever covers one, plus a ring just outside the
grid's border (the walls), so that open floors register near their edges too.

Geometry (cell coordinates u = east / c, v = -north / c, as in sim_world.camera):
- a lattice of sites every `spacing` cells (closer on a small floor, so that
  it still has about three a side), offset by half a spacing from the grid's
  top-left corner; each site takes the 2x2 block of obstacle cells whose
  centre is nearest to it, if one lies within `spacing / 3` cells (else the site
  stays empty: open aisles and docks have no shelf to carry a marker);
- the marker's black square is 0.75 of the block's side, centred, its top edge
  facing north; the rest of the block is its white quiet zone;
- if fewer than half the sites find a 2x2 block (a random map's scattered
  obstacles), the whole map uses single obstacle cells (1x1 blocks) instead:
  one marker size per map, as WorldInfo publishes one `landmark_size_m`;
- the ring: blocks of the same size whose centres lie one block-half outside the
  grid, every `spacing` cells along each side, corners included.

Ids: DICT_5X5_1000 (robots carry DICT_4X4_1000, so the two never read as each
other). When the lattice (ring included) has at most 1000 sites, every site has
its own id. A bigger map reuses ids periodically: the id of lattice site (i, j)
is (i mod 31) + 31 * (j mod 31), so two markers with the same id are at least
31 * spacing cells apart (372 cells at the default spacing) -- far beyond any pose
error; perception takes the instance nearest to where its pose estimate says.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocol.errors import MapError

LANDMARK_FAMILY = "DICT_5X5_1000"
LANDMARK_IDS = 1000
ID_PERIOD = 31                 # 31 * 31 = 961 <= 1000 ids
DEFAULT_SPACING = 12           # cells: a close look (~30 cells across) still holds several
MARKER_FRACTION = 0.75         # black square side / block side


@dataclass(frozen=True)
class LandmarkSet:
    family: str                                    # OpenCV ArUco dictionary name
    size_m: float                                  # side of each marker's black square
    landmarks: list[tuple[int, float, float]]      # (id, east_m, north_m) of each marker's centre
    block_cells: int = 2                           # side of the (obstacle) block each marker fills

    def centres_cells(self, cell_size_m: float) -> np.ndarray:
        """[N, 2] marker centres in cell coordinates (u = east / c, v = -north / c)."""
        if not self.landmarks:
            return np.zeros((0, 2))
        a = np.asarray([(e, n) for _, e, n in self.landmarks], dtype=float)
        return np.stack([a[:, 0] / cell_size_m, -a[:, 1] / cell_size_m], axis=1)


def _nearest_blocks(obstacle_block: np.ndarray, sites: np.ndarray, radius: float) -> list[tuple[int, int] | None]:
    """For each site (x, y) of the lattice: the top-left cell of the nearest marked block within `radius`."""
    from scipy import ndimage   # on use: only the world places landmarks

    if not obstacle_block.any():
        return [None] * len(sites)
    dist, (iy, ix) = ndimage.distance_transform_edt(~obstacle_block, return_indices=True)
    out: list[tuple[int, int] | None] = []
    for sx, sy in sites:
        out.append((int(ix[sy, sx]), int(iy[sy, sx])) if dist[sy, sx] <= radius else None)
    return out


def place_landmarks(free: np.ndarray, cell_size_m: float = 1.0, spacing: int = DEFAULT_SPACING,
                    ring: bool = True) -> LandmarkSet:
    """Markers on obstacle blocks near a lattice, plus a ring outside the border (deterministic)."""
    free = np.asarray(free)
    if free.ndim != 2 or free.size == 0 or free.dtype != bool:
        raise MapError(f"landmarks: the grid must be a non-empty 2-D bool array, got {free.dtype} {free.shape}")
    if not (math.isfinite(cell_size_m) and cell_size_m > 0):
        raise MapError(f"landmarks: cell size must be positive, got {cell_size_m}")
    if not 4 <= spacing <= 10_000:
        raise MapError(f"landmarks: spacing must be in [4, 10000] cells, got {spacing}")
    h, w = free.shape
    # A small floor seen whole in one image still needs several markers: at least ~3 sites a side.
    spacing = max(4, min(spacing, min(w, h) // 3))
    off = spacing // 2
    cols = list(range(off, w, spacing)) or [w // 2]
    rows = list(range(off, h, spacing)) or [h // 2]
    # A block's anchor is its top-left cell; the nearest-anchor search runs on the
    # anchor nearest to the site's block centre, i.e. the site shifted up-left by half a block.
    obstacle = ~free
    blocks2 = obstacle[:-1, :-1] & obstacle[1:, :-1] & obstacle[:-1, 1:] & obstacle[1:, 1:] \
        if h > 1 and w > 1 else np.zeros((max(h - 1, 1), max(w - 1, 1)), bool)
    radius = spacing / 3
    grid_sites = [(i, j, x, y) for j, y in enumerate(rows) for i, x in enumerate(cols)]
    anchors2 = _nearest_blocks(blocks2, np.array([(min(max(x - 1, 0), blocks2.shape[1] - 1),
                                                   min(max(y - 1, 0), blocks2.shape[0] - 1))
                                                  for _, _, x, y in grid_sites]), radius)
    found2 = sum(a is not None for a in anchors2)
    block = 2
    anchors = anchors2
    if found2 * 2 < len(grid_sites) and obstacle.any():
        block = 1
        anchors = _nearest_blocks(obstacle, np.array([(x, y) for _, _, x, y in grid_sites]), radius)
    # (i, j, u, v): lattice indices and block centre in cells.
    placed: list[tuple[int, int, float, float]] = []
    for (i, j, _, _), a in zip(grid_sites, anchors):
        if a is not None:
            placed.append((i, j, a[0] + block / 2, a[1] + block / 2))
    if ring:
        half = block / 2
        left, right, top, bottom = -half, w + half, -half, h + half
        ni, nj = len(cols), len(rows)
        for i, x in enumerate(cols):
            placed.append((i, -1, x + 0.5, top))
            placed.append((i, nj, x + 0.5, bottom))
        for j, y in enumerate(rows):
            placed.append((-1, j, left, y + 0.5))
            placed.append((ni, j, right, y + 0.5))
        placed += [(-1, -1, left, top), (ni, -1, right, top), (-1, nj, left, bottom), (ni, nj, right, bottom)]
    ni_all, nj_all = len(cols) + 2, len(rows) + 2
    unique = ni_all * nj_all <= LANDMARK_IDS
    out: list[tuple[int, float, float]] = []
    for i, j, u, v in placed:
        if unique:
            lid = (i + 1) + ni_all * (j + 1)
        else:
            lid = (i % ID_PERIOD) + ID_PERIOD * (j % ID_PERIOD)
        out.append((lid, float(u * cell_size_m), float(-v * cell_size_m)))
    out.sort(key=lambda t: (-t[2], t[1]))   # row-major from the north-west: a stable order
    return LandmarkSet(LANDMARK_FAMILY, MARKER_FRACTION * block * cell_size_m, out, block)
