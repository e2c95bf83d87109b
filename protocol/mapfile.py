"""MovingAI `.map` and `.scen` files: the one grid file format every part reads.

A grid is a numpy bool array `free[y, x]` (True = traversable); cells are
`(x, y)`, x the column, y the row, origin top-left, as in the MovingAI files.
Only `.` and `G` are free; every other map character is an obstacle.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import MapError
from .grid import Cell, on_grid

FREE_CHARS = frozenset(".G")


def parse_rows(rows: list[str], name: str = "map") -> np.ndarray:
    """Rows of map characters -> free[y, x]."""
    if not rows:
        raise MapError(f"{name}: the map has no rows")
    width = len(rows[0])
    if width == 0:
        raise MapError(f"{name}: the map has an empty row")
    for i, row in enumerate(rows):
        if len(row) != width:
            raise MapError(f"{name}: row {i} has {len(row)} cells, expected {width}")
    codes = np.frombuffer("".join(rows).encode("ascii", "replace"), dtype=np.uint8)
    free = (codes == ord(".")) | (codes == ord("G"))
    return free.reshape(len(rows), width)


def format_rows(free: np.ndarray) -> list[str]:
    """free[y, x] -> MovingAI rows ('.' free, '@' obstacle)."""
    chars = np.where(free, ord("."), ord("@")).astype(np.uint8)
    return [bytes(r).decode("ascii") for r in chars]


def _read_text(path: Path, what: str) -> str:
    try:
        return path.read_text(encoding="ascii", errors="replace")
    except FileNotFoundError:
        raise MapError(f"{what} file not found: {path}") from None
    except OSError as exc:
        raise MapError(f"cannot read {what} file {path}: {exc.strerror}") from None


def read_map(path: str | Path) -> np.ndarray:
    path = Path(path)
    return parse_map_text(_read_text(path, "map"), str(path))


def parse_map_text(text: str, name: str = "map") -> np.ndarray:
    lines = text.splitlines()
    header: dict[str, str] = {}
    i = 0
    while i < len(lines) and lines[i].strip().lower() != "map":
        parts = lines[i].split()
        if len(parts) == 2:
            header[parts[0].lower()] = parts[1]
        elif lines[i].strip():
            raise MapError(f"{name}: line {i + 1} is not a header line: {lines[i][:40]!r}")
        i += 1
    if i == len(lines):
        raise MapError(f"{name}: no 'map' line: not a MovingAI .map file")
    try:
        height, width = int(header["height"]), int(header["width"])
    except KeyError as exc:
        raise MapError(f"{name}: header lacks {exc.args[0]!r}") from None
    except ValueError:
        raise MapError(f"{name}: height/width are not integers") from None
    if height <= 0 or width <= 0:
        raise MapError(f"{name}: height and width must be positive")
    rows = [ln.rstrip("\r") for ln in lines[i + 1 : i + 1 + height]]
    if len(rows) != height:
        raise MapError(f"{name}: header says {height} rows, file has {len(rows)}")
    free = parse_rows(rows, name)
    if free.shape[1] != width:
        raise MapError(f"{name}: header says width {width}, rows have {free.shape[1]} cells")
    return free


def write_map(path: str | Path, free: np.ndarray) -> None:
    h, w = free.shape
    body = "\n".join(format_rows(free))
    Path(path).write_text(f"type octile\nheight {h}\nwidth {w}\nmap\n{body}\n", encoding="ascii")


@dataclass(frozen=True)
class ScenAgent:
    start: Cell
    goal: Cell
    length: float = 0.0


def read_scen(path: str | Path, free: np.ndarray | None = None, agents: int | None = None) -> list[ScenAgent]:
    """The first `agents` lines of a scen file; with `free`, checks cells are on free cells."""
    path = Path(path)
    lines = _read_text(path, "scenario").splitlines()
    out: list[ScenAgent] = []
    for n, line in enumerate(lines, 1):
        if agents is not None and len(out) >= agents:
            break
        if not line.strip() or line.lower().startswith("version"):
            continue
        parts = line.split("\t") if "\t" in line else line.split()
        if len(parts) < 8:
            raise MapError(f"{path}: line {n} has {len(parts)} fields, expected 9")
        try:
            sx, sy, gx, gy = (int(p) for p in parts[4:8])
            length = float(parts[8]) if len(parts) > 8 else 0.0
        except ValueError:
            raise MapError(f"{path}: line {n} has a non-numeric coordinate") from None
        if min(sx, sy, gx, gy) < 0:  # numpy would read free[-1, x] as the last row, silently
            raise MapError(f"{path}: line {n} has a negative coordinate")
        a = ScenAgent((sx, sy), (gx, gy), length)
        if free is not None:
            for what, (x, y) in (("start", a.start), ("goal", a.goal)):
                if not on_grid(x, y, free.shape[1], free.shape[0]) or not free[y, x]:
                    raise MapError(f"{path}: line {n}: {what} ({x}, {y}) is not a free cell of the map")
        out.append(a)
    if agents is not None and len(out) < agents:
        raise MapError(f"{path}: asked for {agents} agents, the file has {len(out)}")
    return out


def write_scen(path: str | Path, map_name: str, free: np.ndarray, agents: list[ScenAgent]) -> None:
    h, w = free.shape
    lines = ["version 1"]
    for a in agents:
        lines.append(
            f"0\t{map_name}\t{w}\t{h}\t{a.start[0]}\t{a.start[1]}\t{a.goal[0]}\t{a.goal[1]}\t{a.length:.8f}"
        )
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")
