"""Where the benchmark instances are: shipped with the package, regenerated, or given with `--data`.

The MovingAI maps and scenarios (random-1..5 and even-1..5 of nine maps) and the
paper warehouse's scenarios ship in `scenarios/data/`. The paper's 450x450
warehouse map itself is not shipped: the seeded generator makes it cell for cell,
and the result is checked against the hash of the published file, so a change to
the generator cannot silently change the benchmark. Very large optional sets (the
10,000-agent scenario) come from `--data DIR`, laid out like `data/`.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from protocol.errors import MapError

from .maps import DATA, NAMED, movingai_path, resolve_map, warehouse

PAPER_DIR = "paper-warehouse-450"
PAPER_MAP = "warehouse-450"
# sha256 of f"{width}x{height}:" + np.packbits(free) of the published warehouse-450.map.
PAPER_MAP_SHA256 = "b2c5d9e9af6e009590122ab3a366472590de9f2e7bcacff73bdec652cd32bcc9"


def grid_hash(free: np.ndarray) -> str:
    h, w = free.shape
    return hashlib.sha256(f"{w}x{h}:".encode() + np.packbits(free.astype(bool)).tobytes()).hexdigest()


def paper_warehouse() -> np.ndarray:
    """The paper's 450x450 warehouse, regenerated and checked against the published map's hash."""
    free = warehouse(**NAMED[PAPER_MAP])
    if grid_hash(free) != PAPER_MAP_SHA256:
        raise MapError(f"the generated {PAPER_MAP} differs from the published benchmark map (hash mismatch)")
    return free


def data_file(relative: str, data: str | Path | None = None) -> Path:
    """A benchmark file: from `data` when given, else the shipped copy; one line naming what is missing."""
    root = Path(data) if data else DATA
    path = root / relative
    if not path.is_file():
        hint = "" if data else " (it is not shipped with the package: give --data DIR holding it)"
        raise MapError(f"benchmark file not found: {path}{hint}")
    return path


def movingai_map(name: str, data: str | Path | None = None) -> Path:
    return data_file(movingai_path(name), data)


def movingai_scen(name: str, scen: str, data: str | Path | None = None) -> Path:
    """`scen` as in the file names: random-1, even-3, 10000agents-1 ..."""
    return data_file(movingai_path(name, scen), data)


def paper_map_spec(data: str | Path | None = None) -> str:
    """The paper warehouse as a map spec: a map file under `data` if it holds one, else the generator."""
    given = Path(data) / PAPER_DIR / f"{PAPER_MAP}.map" if data else None
    return str(given) if given is not None and given.is_file() else PAPER_MAP


def load_map(spec: str) -> np.ndarray:
    """A benchmark map spec -> free[y, x]; the paper warehouse is checked against its hash."""
    return paper_warehouse() if spec == PAPER_MAP else resolve_map(spec)[1]


def paper_scen(which: int = 1, data: str | Path | None = None) -> Path:
    return data_file(f"{PAPER_DIR}/{PAPER_MAP}-random-{which}.scen", data)
