"""MovingAI `.map` and `.scen` files: the one grid file format every part reads.

A grid is a numpy bool array `free[y, x]` (True = traversable); cells are
`(x, y)`, x the column, y the row, origin top-left, as in the MovingAI files.
Only `.` and `G` are free; every other map character is an obstacle.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .errors import MapError
from .grid import MAX_GRID_SIDE, Cell, on_grid
from .log import printable

FREE_CHARS = frozenset(".G")
MAX_CELLS = 1 << 24          # 4096 x 4096: the planners' tables for such a floor already take gigabytes
MAX_HEADER_BYTES = 1 << 16   # a MovingAI header is four short lines; what precedes 'map' past this is not one

SizeCheck = Callable[[int, int, str], None]   # (width, height, what): raises MapError for a floor too large


def check_size(width: int, height: int, what: str) -> None:
    """Before allocating or reading rows: a typo in a size must be a line, not gigabytes."""
    if width > MAX_GRID_SIDE or height > MAX_GRID_SIDE:
        raise MapError(f"{what}: {width}x{height} cells exceeds the protocol's {MAX_GRID_SIDE} cells per side")
    if width * height > MAX_CELLS:
        raise MapError(f"{what}: {width}x{height} is {width * height:,} cells, more than {MAX_CELLS:,}")


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


def _shown(path: Path) -> str:
    """A file name in an error line: one line, whatever the name holds, and not too long."""
    text = printable(str(path))
    return text if len(text) <= 120 else text[:120] + "..."


def _open_error(exc: OSError | ValueError, what: str, path: Path) -> MapError:
    shown = _shown(path)
    if isinstance(exc, FileNotFoundError):
        return MapError(f"{what} file not found: {shown}")
    if isinstance(exc, ValueError):   # a NUL byte in the name
        return MapError(f"cannot read {what} file {shown!r}: not a file name")
    return MapError(f"cannot read {what} file {shown}: {exc.strerror or exc}")


def _read_text(path: Path, what: str) -> str:
    try:
        return path.read_text(encoding="ascii", errors="replace")
    except (OSError, ValueError) as exc:
        raise _open_error(exc, what, path) from None


def read_map(path: str | Path, check: SizeCheck = check_size) -> np.ndarray:
    """A MovingAI .map file; its header's size passes `check` before a row is read, so a huge
    floor is one line, not gigabytes."""
    path = Path(path)
    name = _shown(path)
    try:
        with path.open("rb") as f:
            head = f.read(MAX_HEADER_BYTES)
            if len(head) < MAX_HEADER_BYTES:   # the whole file
                return parse_map_text(head.decode("ascii", "replace"), name, check)
            lines = head.decode("ascii", "replace").splitlines(keepends=True)[:-1]   # the last may be cut
            at = next((i for i, ln in enumerate(lines) if ln.strip().lower() == "map"), None)
            if at is None:
                raise MapError(f"{name}: no 'map' line in its first {MAX_HEADER_BYTES:,} bytes: "
                               "not a MovingAI .map file")
            height, width = _header([ln.rstrip("\r\n") for ln in lines[:at]], name, check)
            done = sum(map(len, lines[:at + 1]))   # one character a byte, as decoded
            # The rows: height lines of width cells and a CR LF each at most; what follows is not read.
            rest = head[done:] + f.read(max(0, height * (width + 2) - (len(head) - done)))
    except (OSError, ValueError) as exc:
        raise _open_error(exc, "map", path) from None
    return _rows(rest.decode("ascii", "replace").splitlines(), height, width, name)


def parse_map_text(text: str, name: str = "map", check: SizeCheck = check_size) -> np.ndarray:
    lines = text.splitlines()
    i = next((i for i, ln in enumerate(lines) if ln.strip().lower() == "map"), len(lines))
    if i == len(lines):
        raise MapError(f"{name}: no 'map' line: not a MovingAI .map file")
    height, width = _header(lines[:i], name, check)
    return _rows(lines[i + 1:], height, width, name)


def _header(lines: list[str], name: str, check: SizeCheck) -> tuple[int, int]:
    """The header lines before 'map' -> (height, width), checked."""
    header: dict[str, str] = {}
    for i, line in enumerate(lines):
        parts = line.split()
        if len(parts) == 2:
            header[parts[0].lower()] = parts[1]
        elif line.strip():
            raise MapError(f"{name}: line {i + 1} is not a header line: {line[:40]!r}")
    try:
        height, width = int(header["height"]), int(header["width"])
    except KeyError as exc:
        raise MapError(f"{name}: header lacks {exc.args[0]!r}") from None
    except ValueError:
        raise MapError(f"{name}: height/width are not integers") from None
    if height <= 0 or width <= 0:
        raise MapError(f"{name}: height and width must be positive")
    check(width, height, name)
    return height, width


def _rows(lines: list[str], height: int, width: int, name: str) -> np.ndarray:
    rows = [ln.rstrip("\r") for ln in lines[:height]]
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
    name = _shown(path)
    lines = _read_text(path, "scenario").splitlines()
    out: list[ScenAgent] = []
    for n, line in enumerate(lines, 1):
        if agents is not None and len(out) >= agents:
            break
        if not line.strip() or line.lower().startswith("version"):
            continue
        parts = line.split("\t") if "\t" in line else line.split()
        if len(parts) < 8:
            raise MapError(f"{name}: line {n} has {len(parts)} fields, expected 9")
        try:
            sx, sy, gx, gy = (int(p) for p in parts[4:8])
            length = float(parts[8]) if len(parts) > 8 else 0.0
        except ValueError:
            raise MapError(f"{name}: line {n} has a non-numeric coordinate") from None
        if min(sx, sy, gx, gy) < 0:  # numpy would read free[-1, x] as the last row, silently
            raise MapError(f"{name}: line {n} has a negative coordinate")
        a = ScenAgent((sx, sy), (gx, gy), length)
        if free is not None and (parts[2], parts[3]) != (str(free.shape[1]), str(free.shape[0])):
            raise MapError(f"{name}: line {n} is for the map {parts[1]!r} of {parts[2]}x{parts[3]} cells, "
                           f"not this {free.shape[1]}x{free.shape[0]} floor")
        if free is not None:
            for what, (x, y) in (("start", a.start), ("goal", a.goal)):
                if not on_grid(x, y, free.shape[1], free.shape[0]) or not free[y, x]:
                    raise MapError(f"{name}: line {n}: {what} ({x}, {y}) is not a free cell of the map")
        out.append(a)
    if agents is not None and len(out) < agents:
        raise MapError(f"{name}: asked for {agents} agents, the file has {len(out)}")
    return out


def write_scen(path: str | Path, map_name: str, free: np.ndarray, agents: list[ScenAgent]) -> None:
    h, w = free.shape
    lines = ["version 1"]
    for a in agents:
        lines.append(
            f"0\t{map_name}\t{w}\t{h}\t{a.start[0]}\t{a.start[1]}\t{a.goal[0]}\t{a.goal[1]}\t{a.length:.8f}"
        )
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")
