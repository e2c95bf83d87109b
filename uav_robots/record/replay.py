"""replay.mp4 from mission.mcap: robots as coloured discs with their ids, trails, a tick counter and a legend;
on a floor with movers, each tick's people (orange dots), forklifts (yellow bars) and pallets (blue squares).

On a large floor a robot is far smaller than a readable disc, so the video shows the region the robots
use (their cells, plans and goals, with a margin) and draws every disc at least `MIN_RADIUS_PX` whatever
a cell's size on screen.
"""
from __future__ import annotations

import shutil
import threading
from pathlib import Path

import cv2
import numpy as np

from uav_agent.visualize import FLOOR, SHELF, _palette

from .recording import Recording, mover_kinds, movers_per_tick

VIDEO = "replay.mp4"
MAX_SIDE_PX = 1400      # the map part of a frame, before the legend
MIN_RADIUS_PX = 7
TRAIL = 12              # ticks of trail behind each robot
LEGEND_PX = 300
FPS = 10
FONT = cv2.FONT_HERSHEY_SIMPLEX
# BGR, as the live view's: no robot's disc and id, no goal's ring; the shape tells a mover from a robot.
MOVER_BGR = {"person": (14, 127, 255), "forklift": (0, 212, 255), "pallet": (214, 95, 31)}
MOVER_INK = (34, 34, 34)


def region(rec: Recording, margin: int = 3) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1), exclusive ends: every cell a robot stood on, planned or aimed at, with a margin."""
    pts = [c for cells in rec.cells.values() for c in cells.values()]
    pts += list(rec.goals.values()) + [c for p in rec.paths.values() for c in p]
    h, w = rec.free.shape
    if not pts:
        return 0, 0, w, h
    xs, ys = [p[0] for p in pts], [p[1] for p in pts]
    return (max(0, min(xs) - margin), max(0, min(ys) - margin), min(w, max(xs) + margin + 1),
            min(h, max(ys) + margin + 1))


def layout(rec: Recording) -> tuple[tuple[int, int, int, int], int, int]:
    """(region, pixels per cell, disc radius)."""
    x0, y0, x1, y1 = region(rec)
    s = max(1, min(24, MAX_SIDE_PX // max(x1 - x0, y1 - y0)))
    return (x0, y0, x1, y1), s, max(MIN_RADIUS_PX, int(s * 0.42))


def _positions(rec: Recording) -> dict[int, list[tuple[int, int]]]:
    """Each robot's cell at ticks 0..ticks, holding its last reported cell where a state is missing."""
    out = {}
    for rid, by_tick in rec.cells.items():
        # A robot reports a state after each tick; before its first, it stood on its plan's start.
        last, seq = rec.starts.get(rid, by_tick[min(by_tick)]), []
        for t in range(rec.ticks + 1):
            last = by_tick.get(t, last)
            seq.append(last)
        out[rid] = seq
    return out


class Cancelled(Exception):
    """The caller no longer wants the video (`render`'s `cancel` was set)."""


def render(rec: Recording, path: Path, fps: int = FPS, cancel: threading.Event | None = None) -> tuple[int, int, int]:
    """Write the video, frames 0..rec.ticks (bound them first: `recording.bound`); returns (frames, width,
    height). OSError if the file is not whole (OpenCV says nothing when a frame is not written:
    a full disk); Cancelled, between two frames, once `cancel` is set."""
    (x0, y0, x1, y1), s, r = layout(rec)
    free = rec.free[y0:y1, x0:x1]
    base = np.where(free[..., None], np.array(FLOOR, np.uint8), np.array(SHELF, np.uint8))
    base = cv2.resize(base, (free.shape[1] * s, free.shape[0] * s), interpolation=cv2.INTER_NEAREST)
    pad = r + 2   # room for discs on the edge cells
    base = cv2.copyMakeBorder(base, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=FLOOR)
    mh, mw = base.shape[:2]
    height = max(mh, 360) + (max(mh, 360) % 2)
    width = mw + LEGEND_PX + (mw % 2)
    ids = sorted(rec.cells)
    colours = dict(zip(ids, _palette(len(ids))))

    def px(c: tuple[int, int]) -> tuple[int, int]:
        return (c[0] - x0) * s + s // 2 + pad, (c[1] - y0) * s + s // 2 + pad

    for rid, goal in rec.goals.items():
        if rid in colours:
            cv2.circle(base, px(goal), r, colours[rid], 2, cv2.LINE_AA)
    pos = _positions(rec)
    movers = movers_per_tick(rec) if rec.movers else []
    # Each robot's pixel per tick and its label's layout, once: per frame and robot they cost more
    # than the drawing (a 1,000-robot mission's 176 frames took 14 s).
    at = {rid: np.array([px(c) for c in pos[rid]], np.int32) for rid in ids}
    text_scale = max(0.35, r / 18)
    labels = {rid: _label_layout(str(rid), r, text_scale, colours[rid]) for rid in ids}
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    if not writer.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path} (mp4v)")
    blank = np.full((height, width, 3), 255, np.uint8)
    blank[:mh, :mw] = base
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)   # not a warning per frame unwritten
    try:
        for t in range(rec.ticks + 1):
            if cancel is not None and cancel.is_set():
                raise Cancelled()
            frame = blank.copy()
            for rid in ids:
                trail = at[rid][max(0, t - TRAIL):t + 1]
                # a robot that stood still the whole trail would draw a dot its disc covers
                if len(trail) > 1 and (trail != trail[-1]).any():
                    cv2.polylines(frame, [trail], False, colours[rid], max(2, r // 3), cv2.LINE_AA)
            arrived = 0
            for rid in ids:
                c = pos[rid][t]
                arrived += rec.goals.get(rid) == c
                centre = (int(at[rid][t, 0]), int(at[rid][t, 1]))
                cv2.circle(frame, centre, r, colours[rid], -1, cv2.LINE_AA)
                cv2.circle(frame, centre, r, (0, 0, 0), 1, cv2.LINE_AA)
                label, dx, dy, scale, ink = labels[rid]
                cv2.putText(frame, label, (centre[0] - dx, centre[1] + dy), FONT, scale, ink, 1, cv2.LINE_AA)
            if movers:
                _draw_movers(frame, movers[t], px, r, (x0, y0, x1, y1))
            _legend(frame, mw + 10, t, rec.ticks, arrived, len(ids), (x0, y0, x1, y1), colours,
                    _movers_lines(movers[t], rec.contacts, t) if movers else [])
            writer.write(frame)
    finally:
        writer.release()
        cv2.utils.logging.setLogLevel(level)
    if not whole_mp4(path):
        raise OSError(f"{path.name} is incomplete: OpenCV could not write every frame "
                      f"({shutil.disk_usage(path.parent).free // 2**20} MB free there)")
    return rec.ticks + 1, width, height


def whole_mp4(path: Path) -> bool:
    """Whether an MP4 file is whole: its top-level boxes end where the file ends, the index (moov,
    written last) among them."""
    size, pos, kinds = path.stat().st_size, 0, set()
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            head = f.read(16)
            n = int.from_bytes(head[:4], "big") if len(head) >= 8 else 0
            if n == 1 and len(head) == 16:
                n = int.from_bytes(head[8:16], "big")
            elif n == 0 and len(head) >= 8:
                n = size - pos
            if n < 8:
                return False
            kinds.add(head[4:8])
            pos += n
    return pos == size and b"moov" in kinds


def _label_layout(label: str, r: int, scale: float, colour) -> tuple[str, int, int, float, tuple[int, int, int]]:
    """The id inside its disc: shrunk to fit, black or white, whichever reads on the disc's colour:
    (text, offset left and down from the disc's centre, scale, ink)."""
    (tw, th), _ = cv2.getTextSize(label, FONT, scale, 1)
    if tw > 2 * r - 2:
        scale *= (2 * r - 2) / tw
        (tw, th), _ = cv2.getTextSize(label, FONT, scale, 1)
    b, g, r_ = colour
    ink = (0, 0, 0) if 0.114 * b + 0.587 * g + 0.299 * r_ > 110 else (255, 255, 255)
    return label, tw // 2, th // 2, scale, ink


def _draw_movers(frame: np.ndarray, movers: dict, px, r: int, box) -> None:
    """Over the robots (a mover on a robot's cell is a collision: both stay in sight, the disc around the
    mover); those outside the drawn region are left out, as the floor there is."""
    x0, y0, x1, y1 = box
    for kind, cell in movers.values():
        if not (x0 <= cell[0] < x1 and y0 <= cell[1] < y1):
            continue
        cx, cy = px(cell)
        colour = MOVER_BGR.get(kind, (150, 150, 150))
        if kind == "person":
            cv2.circle(frame, (cx, cy), max(3, r // 2), colour, -1, cv2.LINE_AA)
            cv2.circle(frame, (cx, cy), max(3, r // 2), MOVER_INK, 1, cv2.LINE_AA)
            continue
        hw, hh = (r * 9 // 10, r * 11 // 20) if kind == "forklift" else (r * 13 // 20, r * 13 // 20)
        cv2.rectangle(frame, (cx - hw, cy - hh), (cx + hw, cy + hh), colour, -1)
        cv2.rectangle(frame, (cx - hw, cy - hh), (cx + hw, cy + hh), MOVER_INK, 1)


def _movers_lines(movers: dict, contacts: list[int], t: int) -> list[tuple[str, float, int]]:
    """The legend's lines of a floor with movers: how many stand on it and, from the world's record, the
    robot-mover contacts up to this tick."""
    lines = [(f"movers {len(movers)}: " + mover_kinds(kind for kind, _ in movers.values()), 0.45, 1),
             ("dot person, bar forklift, square pallet", 0.45, 1)]
    if contacts:
        lines.append((f"robot-mover contacts {sum(1 for c in contacts if c <= t)}/{len(contacts)}", 0.45, 1))
    return lines


def _legend(frame: np.ndarray, x: int, t: int, ticks: int, arrived: int, n: int, box, colours,
            extra: list[tuple[str, float, int]] | None = None) -> None:
    lines = [(f"tick {t}/{ticks}", 0.8, 2), (f"on goal {arrived}/{n}", 0.6, 1),
             (f"cells x {box[0]}-{box[2] - 1}, y {box[1]}-{box[3] - 1}", 0.45, 1),
             ("disc: robot (id), ring: its goal", 0.45, 1), ("line: its last moves", 0.45, 1), *(extra or [])]
    y = 32
    for text, scale, thick in lines:
        cv2.putText(frame, text, (x, y), FONT, scale, (0, 0, 0), thick, cv2.LINE_AA)
        y += int(34 * scale) + 8
    per_col = max(1, (frame.shape[0] - y - 10) // 16)
    for i, (rid, col) in enumerate(colours.items()):
        cx, cy = x + 8 + (i // per_col) * 70, y + 8 + (i % per_col) * 16
        if cx + 60 > frame.shape[1]:
            break
        cv2.circle(frame, (cx, cy), 6, col, -1, cv2.LINE_AA)
        cv2.putText(frame, str(rid), (cx + 10, cy + 5), FONT, 0.4, (0, 0, 0), 1, cv2.LINE_AA)


def timeline(rec: Recording, report: dict | None = None) -> dict:
    """The whole mission for the view's replay mode: cells per tick, plans, events, images with their tick;
    on a floor with movers, each mover's kind and cell per tick (null before it came onto the floor) and,
    from `report`, the robot-mover collisions and near misses."""
    import base64
    import bisect

    from ..view.state import movers_outcome

    times = [ns for ns, _ in sorted(rec.tick_times)]
    poses = sorted(rec.poses, key=lambda p: p[0])
    pose_times = [ns for ns, _ in poses]

    def pose_at(ns: int) -> dict:
        """The vehicle's last pose at or before `ns` (its feed runs at about 5 Hz, images come when taken)."""
        i = bisect.bisect_right(pose_times, ns)
        return poses[i - 1][1] if i else {}

    images = [{"tick": bisect.bisect_right(times, ns), "pose": pose_at(ns),
               "data": "data:image/jpeg;base64," + base64.b64encode(jpeg).decode()} for ns, jpeg in rec.images]
    return {"ticks": rec.ticks, "robots": {str(r): [list(c) for c in cells] for r, cells in _positions(rec).items()},
            "goals": {str(r): list(g) for r, g in rec.goals.items()},
            "paths": {str(r): [list(c) for c in p] for r, p in rec.paths.items()},
            "events": rec.events, "images": images, "end": rec.end,
            **({"movers": _mover_cells(rec)} if rec.movers else {}),
            **({"movers_outcome": outcome} if (outcome := movers_outcome(report or {})) else {})}


def _mover_cells(rec: Recording) -> dict[str, dict]:
    """{id: {kind, cells: [[x, y] or None per tick]}}: each mover's track for the view's time slider."""
    per_tick = movers_per_tick(rec)
    out: dict[str, dict] = {}
    for t, movers in enumerate(per_tick):
        for mid, (kind, cell) in movers.items():
            out.setdefault(str(mid), {"kind": kind, "cells": [None] * len(per_tick)})["cells"][t] = list(cell)
    return out
