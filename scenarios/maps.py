"""Warehouse and random map generators, map specs, and placement of robots and goals.

A map spec is what `--map` accepts: a `.map` file path, a named map
(`warehouse-small`, `warehouse-450`), or a generator with parameters
(`warehouse:blocks_x=8,blocks_y=10`, `random:width=32,height=32,density=0.2`).
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from protocol.errors import MapError
from protocol.mapfile import Cell, SizeCheck, check_size, read_map


def warehouse(blocks_x: int, blocks_y: int, shelf_w: int = 10, shelf_h: int = 2, aisle: int = 2,
              dock: int = 27, margin: int = 1, check: SizeCheck = check_size) -> np.ndarray:
    """Shelf blocks in a rectangular array, aisles between, docks left and right, a wall around.

    `warehouse(33, 112)` is the paper's 450x450 warehouse, cell for cell the
    one in `shared/benchmarks/paper-warehouse-450/`.
    """
    for name, v in (("blocks_x", blocks_x), ("blocks_y", blocks_y), ("shelf_w", shelf_w), ("shelf_h", shelf_h)):
        if v < 1:
            raise MapError(f"warehouse: {name} must be at least 1, got {v}")
    if aisle < 1 or dock < 1 or margin < 1:
        raise MapError("warehouse: aisle, dock and margin must be at least 1 cell")
    width = 2 + 2 * dock + blocks_x * shelf_w + (blocks_x - 1) * aisle
    height = 2 + 2 * margin + blocks_y * shelf_h + (blocks_y - 1) * aisle
    check(width, height, "warehouse")
    free = np.ones((height, width), dtype=bool)
    free[0, :] = free[-1, :] = free[:, 0] = free[:, -1] = False
    for by in range(blocks_y):
        y0 = 1 + margin + by * (shelf_h + aisle)
        for bx in range(blocks_x):
            x0 = 1 + dock + bx * (shelf_w + aisle)
            free[y0:y0 + shelf_h, x0:x0 + shelf_w] = False
    return free


def random_map(width: int, height: int, density: float, seed: int, check: SizeCheck = check_size) -> np.ndarray:
    """Obstacles on a `density` fraction of cells, uniformly at random (seeded)."""
    if width < 2 or height < 2:
        raise MapError(f"random map: size {width}x{height} is too small")
    check(width, height, "random map")
    if not 0.0 <= density < 1.0:
        raise MapError(f"random map: density must be in [0, 1), got {density}")
    _check_seed(seed, "random map: seed")
    rng = np.random.default_rng(seed)
    free = np.ones(width * height, dtype=bool)
    free[rng.choice(width * height, size=int(round(density * width * height)), replace=False)] = False
    return free.reshape(height, width)


# `--map`'s help, for every command that takes one.
MAP_HELP = ("a .map file (or the name of a shipped MovingAI map), warehouse-small, warehouse-450, "
            "'warehouse:blocks_x=..,blocks_y=..' or 'random:width=..,height=..,density=..'")
NAMED = {
    "warehouse-small": dict(blocks_x=3, blocks_y=4, shelf_w=4, shelf_h=2, aisle=2, dock=3, margin=1),
    "warehouse-450": dict(blocks_x=33, blocks_y=112),
}


def _check_seed(seed: object, what: str) -> None:
    """numpy's generators take no negative seed (their ValueError was a traceback)."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise MapError(f"{what} must be a whole number >= 0, got {_short(seed)}")


def _short(value: object) -> str:
    """A value the user gave, in an error line: never the whole of a long one."""
    text = repr(value) if isinstance(value, str) else str(value)
    return text if len(text) <= 60 else text[:60] + "..."


def _params(text: str, spec: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for part in filter(None, text.split(",")):
        key, sep, value = part.partition("=")
        try:
            number = float(value)
        except ValueError:
            raise MapError(f"map spec {_short(spec)}: {_short(part)} is not name=number") from None
        if not sep:
            raise MapError(f"map spec {_short(spec)}: {_short(part)} is not name=number")
        if not math.isfinite(number):
            raise MapError(f"map spec {_short(spec)}: {_short(part)} is not a finite number")
        out[key.strip()] = number
    return out


def _int(p: dict[str, float], key: str, spec: str) -> int:
    """A generator's whole-number parameter: 2.5 cells or 1e300 blocks is a line, not a surprise."""
    v = p[key]
    if v != int(v) or abs(v) > 2**53:
        raise MapError(f"map spec {_short(spec)}: {key}={v:g} is not a whole number")
    return int(v)


DATA = Path(__file__).resolve().parent / "data"     # the benchmark files that ship with the package


def movingai_path(name: str, scen: str | None = None) -> str:
    """Where a MovingAI map (or, given `scen` as random-1, even-3 ..., its scenario) lies under a
    data directory laid out as `DATA`."""
    return f"movingai/{name}/{name}.map" if scen is None else f"movingai/{name}/{name}-{scen}.scen"


def shipped_movingai(name: str, scen: str | None = None) -> Path | None:
    """The shipped MovingAI map `name` (or its scenario `scen`), None if none ships by that name."""
    if any("/" in part or part in ("", ".", "..") for part in (name, scen) if part is not None):
        return None   # a name, not a way out of the data directory
    path = DATA / movingai_path(name, scen)
    return path if _is_file(str(path)) else None


def _is_file(spec: str) -> bool:
    """Whether `spec` names a file; a name the system cannot take (too long, a NUL byte) names none."""
    try:
        return Path(spec).is_file()
    except (OSError, ValueError):
        return False


def resolve_map(spec: str, seed: int = 0, check: SizeCheck = check_size) -> tuple[str, np.ndarray]:
    """A `--map` value -> (name, free[y, x]); `check` sees the floor's size before it is built or read
    (a mission passes scenarios.limits.check_floor)."""
    _check_seed(seed, "the seed")
    if spec.endswith(".map") or _is_file(spec):
        return Path(spec).stem, read_map(spec, check)
    if spec in NAMED:
        return spec, warehouse(**NAMED[spec], check=check)
    shipped = shipped_movingai(spec)
    if shipped is not None:
        return spec, read_map(shipped, check)
    kind, _, rest = spec.partition(":")
    if kind in ("warehouse", "random"):
        p = _params(rest, spec)
        if kind == "warehouse":
            known = ("blocks_x", "blocks_y", "shelf_w", "shelf_h", "aisle", "dock", "margin")
            unknown = sorted(set(p) - set(known))
            if unknown or not {"blocks_x", "blocks_y"} <= set(p):
                raise MapError(f"map spec {_short(spec)}: a warehouse takes blocks_x and blocks_y, and "
                               f"optionally {', '.join(known[2:])}" + (f", not {_short(unknown[0])}" if unknown else ""))
            return spec, warehouse(**{k: _int(p, k, spec) for k in p}, check=check)
        unknown = sorted(set(p) - {"width", "height", "density", "seed"})
        if unknown:
            raise MapError(f"map spec {_short(spec)}: a random map takes width, height, density and seed, "
                           f"not {_short(unknown[0])}")
        p = {"width": 32, "height": 32, "density": 0.2, "seed": seed, **p}
        return spec, random_map(_int(p, "width", spec), _int(p, "height", spec), p["density"],
                                _int(p, "seed", spec), check)
    raise MapError(f"unknown map {_short(spec)}: give a .map file, {', '.join(NAMED)}, a MovingAI map that ships "
                   "(warehouse-10-20-10-2-1, room-64-64-8, ...: scenarios/data/movingai), "
                   "'warehouse:blocks_x=..,blocks_y=..' or 'random:width=..,height=..,density=..'")


def largest_component(free: np.ndarray) -> np.ndarray:
    """Mask of the largest 4-connected free region: every goal placed in it is reachable."""
    import cv2   # OpenCV's labelling, not scipy.ndimage's: its import alone cost the launcher 0.35 s CPU

    n, labels = cv2.connectedComponents(np.asarray(free, np.uint8), connectivity=4)
    if n <= 1:   # label 0 is the obstacles
        raise MapError("the map has no free cell")
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


@dataclass(frozen=True)
class Placement:
    starts: list[Cell]   # robot i starts at starts[i]
    goals: list[Cell]    # goal j; which robot takes it is the planner's business


def place(free: np.ndarray, robots: int, seed: int) -> Placement:
    """Robots and goals on 2N distinct free cells of the largest connected region (seeded)."""
    if robots < 1:
        raise MapError(f"the number of robots must be at least 1, got {robots}")
    _check_seed(seed, "the seed")
    region = np.flatnonzero(largest_component(free))
    if 2 * robots > region.size:
        raise MapError(f"{robots} robots and {robots} goals need {2 * robots} free connected cells; "
                       f"the map has {region.size}")
    rng = np.random.default_rng(seed)
    cells = rng.choice(region, size=2 * robots, replace=False)
    w = free.shape[1]
    xy = [(int(c % w), int(c // w)) for c in cells]
    return Placement(starts=xy[:robots], goals=xy[robots:])
