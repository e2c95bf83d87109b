"""Pictures of a mission for people: the planned paths and a replay of the executed moves."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from protocol.grid import Cell

FLOOR, SHELF = (235, 235, 235), (60, 60, 60)


def _palette(n: int) -> list[tuple[int, int, int]]:
    hues = (np.arange(max(n, 1)) * 0.61803398875 % 1.0 * 179).astype(np.uint8)
    hsv = np.stack([hues, np.full_like(hues, 200), np.full_like(hues, 220)], axis=1)[None]
    bgr = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0]
    return [tuple(int(c) for c in px) for px in bgr]


def _scale(free: np.ndarray, max_px: int = 1400) -> int:
    return max(1, min(24, max_px // max(free.shape)))


def base_image(free: np.ndarray, scale: int) -> np.ndarray:
    img = np.where(free[..., None], np.array(FLOOR, np.uint8), np.array(SHELF, np.uint8))
    return cv2.resize(img, (free.shape[1] * scale, free.shape[0] * scale), interpolation=cv2.INTER_NEAREST)


def _centre(c: Cell, s: int) -> tuple[int, int]:
    return int(c[0] * s + s // 2), int(c[1] * s + s // 2)


def draw_paths(free: np.ndarray, paths: list[list[Cell]], goals: list[Cell]) -> np.ndarray:
    """The map with every robot's planned path, start (filled) and goal (ring)."""
    s = _scale(free)
    img = base_image(free, s)
    colours = _palette(len(paths))
    r = max(1, s // 3)
    for path, goal, col in zip(paths, goals, colours):
        pts = np.array([_centre(c, s) for c in path], np.int32)
        if len(pts) > 1:
            cv2.polylines(img, [pts], False, col, max(1, s // 6), cv2.LINE_AA)
        cv2.circle(img, _centre(path[0], s), r, col, -1, cv2.LINE_AA)
        cv2.circle(img, _centre(goal, s), r, col, max(1, s // 8), cv2.LINE_AA)
    return img


def write_png(path: str | Path, img: np.ndarray) -> None:
    cv2.imwrite(str(path), img)


def replay_gif(path: str | Path, free: np.ndarray, executed: dict[int, list[Cell]], goals: dict[int, Cell],
               max_frames: int = 150, max_px: int = 600, fps: int = 12) -> int:
    """An animated GIF of the robots as the world recorded them; returns the frame count.

    Frames are drawn straight into palette indices (0 floor, 1 shelf, 2.. robots),
    so no colour quantisation is needed; long missions are sampled down to
    `max_frames` so a 1000-step run stays a small file.
    """
    from PIL import Image

    s = _scale(free, max_px)
    ids = sorted(executed)
    n_colours = min(len(ids), 254)
    slot = {rid: 2 + i % n_colours for i, rid in enumerate(ids)}
    palette = [*FLOOR[::-1], *SHELF[::-1]]
    for b, g, r in _palette(n_colours):
        palette += [r, g, b]
    base = np.kron(np.where(free, 0, 1).astype(np.uint8), np.ones((s, s), np.uint8))
    for rid in ids:
        if rid in goals:
            x, y = goals[rid]
            cv2.rectangle(base, (x * s, y * s), (x * s + s - 1, y * s + s - 1), slot[rid], 1)
    ticks = max((len(v) for v in executed.values()), default=1)
    frames_at = sorted(set(np.linspace(0, ticks - 1, min(ticks, max_frames)).round().astype(int).tolist()))
    r = max(1, s // 2 - 1)
    frames = []
    for t in frames_at:
        idx = base.copy()
        for rid in ids:
            cells = executed[rid]
            cv2.circle(idx, _centre(tuple(cells[min(t, len(cells) - 1)]), s), r, slot[rid], -1)
        img = Image.fromarray(idx, mode="P")
        img.putpalette(palette)
        frames.append(img)
    frames[0].save(str(path), save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0,
                   optimize=False)
    return len(frames)
