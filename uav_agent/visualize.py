"""Pictures of a mission for people: the planned paths and a replay of the executed moves."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

Cell = tuple[int, int]

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

    Long missions are sampled down to `max_frames` so a 1000-step run stays a small file.
    """
    import imageio.v2 as imageio

    s = _scale(free, max_px)
    base = base_image(free, s)
    ids = sorted(executed)
    colours = dict(zip(ids, _palette(len(ids))))
    ticks = max((len(v) for v in executed.values()), default=1)
    frames_at = sorted(set(np.linspace(0, ticks - 1, min(ticks, max_frames)).round().astype(int).tolist()))
    r = max(1, s // 2 - 1)
    frames = []
    for t in frames_at:
        img = base.copy()
        for i in ids:
            if i in goals:
                cv2.rectangle(img, (goals[i][0] * s, goals[i][1] * s),
                              (goals[i][0] * s + s - 1, goals[i][1] * s + s - 1), colours[i], 1)
        for i in ids:
            cells = executed[i]
            c = cells[min(t, len(cells) - 1)]
            cv2.circle(img, _centre(tuple(c), s), r, colours[i], -1)
        frames.append(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    imageio.mimsave(str(path), frames, duration=1.0 / fps, loop=0)
    return len(frames)
