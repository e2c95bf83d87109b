"""Frames -> one world model: every view registered, read, and fused by confidence.

Each view votes on each cell it sees with a weight: its registration quality
(landmarks and a small reprojection error; the bare pose estimate counts
little), its sharpness, how close to the image centre the cell lies, and how
clearly the cell read as floor or shelf. A cell whose weighted votes conflict,
or that only weak views saw, is `unsure`: the mission looks closer before it
treats such a cell as an obstacle. Robot markers are settled by the summed
quality of their readings; landmark cells are known shelf and never a robot.
People, forklifts and pallets (`movers`) stand on floor: their cells are free,
never a marker; where they are is what each cell's latest look showed.
"""
from __future__ import annotations

from collections.abc import Collection
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from protocol.errors import MissionError
from protocol.grid import Cell
from protocol.messages import CameraFrame

from .frames import Frame, Pixels, pixels, reduction
from .goals import goal_blobs, goals_from
from .markers import Sighting, read_faint, read_markers, settle
from .movers import MoverSighting, mover_pixels, movers_from
from .occupancy import MARKER_STD_RATIO, Cells, cells_in
from .registration import Landmarks, Registration, register
from .view import View, px_per_cell, sharpness

ESTIMATE_WEIGHT = 0.05      # a view placed by the pose estimate alone, against one registered by landmarks
UNSURE_AGREEMENT = 0.5      # |weighted vote| / total weight below this: the views disagree
UNSURE_WEIGHT = 0.1         # total weight below this: nothing clear saw the cell (a clear view weighs 0.5..1)
DETECT_CONTRAST = MARKER_STD_RATIO / 2   # cells the marker detector reads: robots >= 0.17, plain floor <= 0.11


@dataclass(frozen=True)
class FrameReport:
    """How one frame was placed on the floor."""
    seq: int
    source: str                       # "landmarks" or "estimate"
    landmarks: int
    reprojection_px: float | None
    pose: tuple[float, ...] | None    # (north, east, down, roll, pitch, yaw) from the landmarks
    sharpness: float


@dataclass(eq=False)
class WorldModel:
    free: np.ndarray                   # bool [height, width]; unseen cells are False
    robots: dict[int, Cell]            # marker id -> cell
    goals: list[Cell]
    seen: np.ndarray                   # bool [height, width]: wholly inside at least one image
    unseen: int                        # cells no image covers
    unidentified: list[Cell] = field(default_factory=list)  # a marker is there, its id unread
    warnings: list[str] = field(default_factory=list)
    unsure: list[Cell] = field(default_factory=list)         # conflicting or weakly seen: blocked until looked at
    frames: list[FrameReport] = field(default_factory=list)
    # People, forklifts, pallets: in each cell, what the latest view that saw it trusted showed
    # (one that has moved on since may stand where an older view saw it, too).
    movers: list[MoverSighting] = field(default_factory=list)


# The goal pads' and the movers' colour splits run beside the registration (OpenCV releases the
# GIL): a frame alone, as the survey's last one is, is read in two thirds of the time. Threads
# enough for the survey's frames measured at once.
_SIDE = ThreadPoolExecutor(4, thread_name_prefix="perception-goals")


def prepare(item: Pixels | Frame | CameraFrame, landmarks: Landmarks | None, cell_size_m: float) -> View:
    return _registered(_sized(item, cell_size_m), landmarks, cell_size_m)


def _sized(item: Pixels | Frame | CameraFrame, cell_size_m: float) -> Pixels:
    """The frame's pixels at the resolution perception reads it at."""
    meta = item.frame.meta if isinstance(item, Pixels) else item.meta if isinstance(item, Frame) else item
    return pixels(item, reduction(meta, cell_size_m))


def _registered(px: Pixels, landmarks: Landmarks | None, cell_size_m: float) -> View:
    gray = px.gray
    reg: Registration = register(gray, px.frame.meta, landmarks, cell_size_m)
    ppc = px_per_cell(reg.H, gray.shape)
    return View(px.frame, px.image, gray, px.valid, reg, reg.H, np.linalg.inv(reg.H), ppc, sharpness(gray, ppc))


def _weight(view: View, landmarks: Landmarks | None) -> float:
    reg = view.reg
    if not reg.registered and landmarks is not None:
        return ESTIMATE_WEIGHT * view.sharpness
    # One landmark pins the view less well than several.
    return view.sharpness / (1.0 + (reg.reprojection_px or 0.0)) * min(1.0, 0.5 + 0.25 * reg.landmarks)


def _within(reg: Registration, cells) -> np.ndarray:
    """Cells of this view close enough to its landmarks for their placement to hold."""
    if not np.isfinite(reg.trust_radius) or reg.anchors is None:
        return np.ones(cells.seen.shape, bool)
    ny, nx = cells.seen.shape
    u = np.arange(cells.x0, cells.x0 + nx) + 0.5
    v = np.arange(cells.y0, cells.y0 + ny) + 0.5
    d = np.full((ny, nx), np.inf)
    for au, av in reg.anchors:
        d = np.minimum(d, np.hypot(u[None, :] - au, v[:, None] - av))
    return d <= reg.trust_radius


@dataclass(eq=False)
class Reading:
    """One frame measured (`Fusion.measure`), not yet merged."""
    view: View
    report: FrameReport
    cells: Cells | None = None         # None: the view shows no cell of the grid
    trusted: np.ndarray | None = None  # cells close enough to the view's landmarks
    weight: np.ndarray | None = None   # each cell's vote weight
    markers: bool = False              # registered: its goals and markers count
    goals: set[Cell] = field(default_factory=set)
    movers: list[MoverSighting] = field(default_factory=list)   # on trusted cells only, as goals
    movers_read: bool = False          # registered: its trusted cells were looked at for movers
    sightings: list[Sighting] = field(default_factory=list)
    faint: list = field(default_factory=list)          # markers.read_markers' faint reads
    warnings: list[str] = field(default_factory=list)


class Fusion:
    """A world model built one frame at a time: `add` each frame as it arrives (the survey
    flies on meanwhile), `model()` whenever the mission needs the current picture."""

    def __init__(self, width: int, height: int, cell_size_m: float, known_ids: Collection[int] | None = None,
                 landmarks: Landmarks | None = None) -> None:
        if width < 1 or height < 1:
            raise MissionError(f"perception: grid size {width}x{height} is not positive")
        if not cell_size_m > 0:
            raise MissionError(f"perception: cell size must be positive, got {cell_size_m}")
        self.grid = (width, height)
        self.cell_size_m, self.known_ids, self.landmarks = cell_size_m, known_ids, landmarks
        self.vote = np.zeros((height, width))       # sum of weight * (+1 floor, -1 shelf)
        self.total = np.zeros((height, width))      # sum of weight
        self.seen = np.zeros((height, width), bool)
        self.marker_vote = np.zeros((height, width))   # weight of the views that see a marker's contrast there
        self.shelf_cells = landmarks.cells(cell_size_m, width, height) if landmarks is not None else set()
        self.sightings: list[Sighting] = []
        self.faint: list = []
        self.goals: set[Cell] = set()
        self.mover_at: dict[Cell, str] = {}          # cell -> kind, as the latest view trusted there showed it
        self.mover_cells: set[Cell] = set()         # every cell a mover was seen on: floor
        self.last_movers: list[MoverSighting] = []  # the movers of the frame merged last (a monitoring image's)
        self.last_checked = np.zeros((height, width), bool)   # ... and the cells it looked for them in
        self.warnings: list[str] = []
        self.reports: list[FrameReport] = []
        self.best = 0.0                             # the heaviest view's weight

    def add(self, item: Pixels | Frame | CameraFrame, movers_only: bool = False) -> View:
        reading = self.measure(item, movers_only)
        self.merge(reading)
        return reading.view

    def measure(self, item: Pixels | Frame | CameraFrame, movers_only: bool = False) -> Reading:
        """Everything one frame says, read without touching the fusion: frames may be measured
        on several threads at once (OpenCV releases the GIL) and merged in their order.
        `movers_only`: the floor and its movers, no goals or markers (a look for movers from high up)."""
        landmarks, grid = self.landmarks, self.grid
        px = _sized(item, self.cell_size_m)
        blobs = None if movers_only else _SIDE.submit(goal_blobs, px.image, px.valid)
        coloured = _SIDE.submit(mover_pixels, px.image, px.valid)
        view = _registered(px, landmarks, self.cell_size_m)
        reg = view.reg
        report = FrameReport(int(view.frame.meta.seq), reg.source, reg.landmarks, reg.reprojection_px,
                             None if reg.pose is None else tuple(round(v, 4) for v in (
                                 reg.pose.north_m, reg.pose.east_m, reg.pose.down_m, reg.pose.roll_rad,
                                 reg.pose.pitch_rad, reg.pose.yaw_rad)), round(view.sharpness, 3))
        cells = cells_in(view, grid)
        if cells is None:
            return Reading(view, report)
        trusted = cells.seen & _within(reg, cells)
        w = _weight(view, landmarks) * cells.centre_weight * (0.25 + 0.75 * cells.confidence) * cells.seen
        w = np.where(trusted, w, ESTIMATE_WEIGHT * w)
        reading = Reading(view, report, cells, trusted, w)
        if landmarks is not None and not reg.registered:
            return reading   # placed by the estimate alone: its cells vote (weakly), its markers and goals would lie

        def inside(cell: Cell) -> bool:   # a trusted cell of this view (a set of them costs 25 ms a frame)
            x, y = cell[0] - cells.x0, cell[1] - cells.y0
            return 0 <= y < trusted.shape[0] and 0 <= x < trusted.shape[1] and bool(trusted[y, x])

        # A mover stands on floor and is drawn bright enough for the occupancy split to read its cell
        # so: the warm haze a blurred forklift casts over a shelf beside it is no mover on that shelf.
        reading.movers = [m for m in movers_from(coloured.result(), view, grid)
                          if m.cell not in self.shelf_cells and inside(m.cell)
                          and cells.free[m.cell[1] - cells.y0, m.cell[0] - cells.x0]]
        reading.movers_read = True
        if movers_only:
            return reading
        reading.goals = {g for g in goals_from(blobs.result(), view, grid) - self.shelf_cells if inside(g)}
        standing = {m.cell for m in reading.movers}
        for x, y in standing:   # no marker is there, whatever contrast a forklift's forks or the blur give it
            cells.marker_like[y - cells.y0, x - cells.x0] = False
        ys, xs = np.nonzero(cells.marker_like & trusted)
        marked = {(int(x) + cells.x0, int(y) + cells.y0) for x, y in zip(xs, ys)} - self.shelf_cells
        # The detector looks wider: at half a marker's contrast (blur dims a marker's white below
        # the in-place test's).
        ys, xs = np.nonzero((cells.contrast > DETECT_CONTRAST) & trusted)
        near = {(int(x) + cells.x0, int(y) + cells.y0) for x, y in zip(xs, ys)} - self.shelf_cells - standing
        # Read in place: the marker-like cells, and the goals the detector looks at. A robot parked
        # on its goal shows its marker inside the pad's green frame, which keeps the cell under the
        # marker-like test (blur 2 on the 450 floor: 3 of 10 parked robots went unread, and the
        # verification counted them as not arrived); an empty pad shows no marker frame, reads nothing.
        candidates = marked | (near & reading.goals)
        reading.sightings = [s for s in read_markers(view, candidates, grid, reading.warnings, near=near | candidates,
                                                     faint=reading.faint)
                             if s.cell not in self.shelf_cells and inside(s.cell)]
        reading.markers = True
        return reading

    def merge(self, reading: Reading) -> None:
        """Fold one measured frame into the model."""
        self.reports.append(reading.report)
        self.last_movers = list(reading.movers)
        self.last_checked = np.zeros_like(self.seen)
        cells = reading.cells
        if cells is None:
            return
        sl = (slice(cells.y0, cells.y0 + cells.seen.shape[0]), slice(cells.x0, cells.x0 + cells.seen.shape[1]))
        if reading.movers_read:   # an image placed by the pose estimate alone says nothing of them
            self.last_checked[sl] = reading.trusted
        self.best = max(self.best, reading.view.sharpness)   # what a registered view of this quality would weigh
        w = reading.weight
        self.vote[sl] += w * np.where(cells.free, 1.0, -1.0)
        self.total[sl] += w
        self.seen[sl] |= cells.seen
        if not reading.markers:
            return
        self.goals |= reading.goals
        self._look_for_movers(reading)
        self.marker_vote[sl] += w * (cells.marker_like & reading.trusted)
        self.warnings += reading.warnings
        self.sightings += reading.sightings
        self.faint += reading.faint

    def _look_for_movers(self, reading: Reading) -> None:
        """The movers of this frame replace what older frames showed in the cells it trusts: movers
        walk on, and the latest look at a cell is the one to go by."""
        cells, trusted = reading.cells, reading.trusted
        for cell in list(self.mover_at):
            x, y = cell[0] - cells.x0, cell[1] - cells.y0
            if 0 <= y < trusted.shape[0] and 0 <= x < trusted.shape[1] and trusted[y, x]:
                del self.mover_at[cell]
        for m in reading.movers:
            self.mover_at[m.cell] = m.kind
            self.mover_cells.add(m.cell)

    def model(self) -> WorldModel:
        """The world model of every frame added so far."""
        vote, total, seen, landmarks = self.vote, self.total, self.seen.copy(), self.landmarks
        shelf_cells, goals, reports = self.shelf_cells, set(self.goals), self.reports
        standing = self.mover_cells
        width, height = self.grid
        warnings = list(self.warnings)
        free = (vote > 0) & seen
        agreement = np.abs(vote) / np.maximum(total, 1e-12)
        # Weak against this mission's best view: blur or noise that is the same everywhere
        # leaves every cell as sure as the images allow.
        unsure_mask = seen & ((agreement < UNSURE_AGREEMENT) | (total < UNSURE_WEIGHT * self.best))
        for x, y in shelf_cells:
            free[y, x], unsure_mask[y, x] = False, False
        robots = settle(self.sightings, self.known_ids, warnings)
        robot_cells = set(robots.values())
        # A marker most views agree on: one misregistered view's contrast at a shelf edge is not one.
        marker_like = self.marker_vote > 0.5 * total
        marked = {(int(x), int(y)) for y, x in zip(*np.nonzero(marker_like))} - shelf_cells
        unidentified = sorted(marked - robot_cells - goals - standing)
        if self.faint and self.known_ids is not None and len(robots) < len(self.known_ids):
            doubt = {cell for cell, _ in self.faint} - robot_cells - goals - shelf_cells - standing
            robots.update(read_faint(self.faint, doubt, sorted(self.known_ids), set(robots), warnings))
            robot_cells = set(robots.values())
            unidentified = sorted(marked - robot_cells - goals - standing)
        for x, y in list(robot_cells) + list(goals) + unidentified + list(standing):
            free[y, x] = seen[y, x] = True   # floor under a robot, a goal marker, a person, a forklift or a pallet
            unsure_mask[y, x] = False
        if unidentified:
            warnings.append(f"{len(unidentified)} marker(s) seen but not read, at {unidentified[:5]}")
        unsure = sorted((int(x), int(y)) for y, x in zip(*np.nonzero(unsure_mask)))
        if unsure:
            free[unsure_mask] = False      # an obstacle until a closer look says otherwise
            warnings.append(f"{len(unsure)} cell(s) unsure (views disagree or only weak views), at {unsure[:5]}")
        estimated = [r.seq for r in reports if r.source != "landmarks"]
        if landmarks is not None and estimated:
            warnings.append(f"{len(estimated)} frame(s) placed by the pose estimate alone (too few landmarks): "
                            f"seq {estimated[:5]}")
        return WorldModel(free=free, robots=robots, goals=sorted(goals), seen=seen,
                          unseen=int(width * height - seen.sum()), unidentified=unidentified, warnings=warnings,
                          unsure=unsure, frames=list(reports),
                          movers=[MoverSighting(kind, cell) for cell, kind in sorted(self.mover_at.items())])


def perceive(frames: list[Frame | CameraFrame], width: int, height: int, cell_size_m: float,
             known_ids: Collection[int] | None = None, landmarks: Landmarks | None = None) -> WorldModel:
    """Merge overhead frames into a world model of a width x height grid.

    `known_ids` (the fleet's robot ids, if the caller knows them from the
    network) turns a marker read as any other id into a warning, not a robot.
    `landmarks` (from WorldInfo) registers each image from the image itself;
    without them the frames' pose estimates are taken as they are."""
    fusion = Fusion(width, height, cell_size_m, known_ids, landmarks)
    for item in frames:
        fusion.add(item)
    return fusion.model()
