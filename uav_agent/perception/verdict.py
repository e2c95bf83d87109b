"""What perception did not see, said as a perception failure, never as a planning one.

A mission cannot plan from a model that misses robots or goals, or that walls a
robot or goal in behind cells it misread as shelf. The planner would say "no
complete assignment", which blames the plan; these checks say what the camera
did not see (which ids, which cells, how many robots against how many goals).
"""
from __future__ import annotations

from collections.abc import Collection

import cv2
import numpy as np

from protocol.errors import MissionError
from protocol.grid import Cell

from .fusion import WorldModel

LIST_MAX = 10


class PerceptionError(MissionError):
    """The camera did not see enough to plan: the message names what is missing."""


def _few(items) -> str:
    items = sorted(items)
    return f"{items[:LIST_MAX]}" + (f" (+{len(items) - LIST_MAX} more)" if len(items) > LIST_MAX else "")


def missing(model: WorldModel, known: Collection[int] | None, expected: int | None) -> str | None:
    """One line naming what the model lacks for a plan, or None when it has it all."""
    problems: list[str] = []
    if model.unseen:
        problems.append(f"{model.unseen} cells seen by no image")
    if known:
        absent = set(known) - set(model.robots)
        if absent:
            problems.append(f"robots {_few(absent)} are alive on the network but not seen")
    if expected is not None and len(model.robots) != expected:
        problems.append(f"{len(model.robots)} robots seen, the mission expects {expected}")
    if len(model.goals) != len(model.robots):
        problems.append(f"{len(model.robots)} robots but {len(model.goals)} goals seen")
    if not problems:
        return None
    if model.unidentified:
        problems.append(f"markers not readable at cells {_few(model.unidentified)}")
    if model.unsure:
        problems.append(f"{len(model.unsure)} cells unsure, e.g. {_few(model.unsure)}")
    return "perception: " + "; ".join(problems)


def walled_in(model: WorldModel, connectivity: int = 4) -> str | None:
    """Robots and goals the perceived floor leaves in a region with a different number of
    each: a misread shelf, or an unsure cell kept as one, cuts them off. None if all regions balance."""
    _, labels = cv2.connectedComponents(model.free.astype(np.uint8), connectivity=connectivity)
    robots: dict[int, list[Cell]] = {}
    goals: dict[int, list[Cell]] = {}
    for c in model.robots.values():
        robots.setdefault(int(labels[c[1], c[0]]), []).append(tuple(c))
    for c in model.goals:
        goals.setdefault(int(labels[c[1], c[0]]), []).append(tuple(c))
    short = [(k, len(robots.get(k, [])), len(goals.get(k, []))) for k in set(robots) | set(goals)
             if len(robots.get(k, [])) > len(goals.get(k, []))]
    if not short:
        return None
    cut_robots = [c for k, _, _ in short for c in robots[k]]
    return (f"perception: the floor as seen walls {len(cut_robots)} robot(s) at {_few(cut_robots)} off from enough "
            f"goals ({sum(r for _, r, _ in short)} robots, {sum(g for _, _, g in short)} goals in their regions)"
            + (f"; {len(model.unsure)} cells were unsure and kept as obstacles, e.g. {_few(model.unsure)}"
               if model.unsure else ""))


def raise_if_missing(model: WorldModel, known: Collection[int] | None, expected: int | None) -> None:
    why = missing(model, known, expected)
    if why:
        raise PerceptionError(why)


def explain_unplannable(model: WorldModel, connectivity: int) -> PerceptionError | None:
    why = walled_in(model, connectivity)
    return PerceptionError(why) if why else None


def unsure_mask(model: WorldModel) -> np.ndarray:
    mask = np.zeros(model.free.shape, bool)
    for x, y in model.unsure:
        mask[y, x] = True
    return mask
