"""What the world lays on the floor besides shelves and robots, for the camera to see: how goals are
marked, and the surveyed landmarks the UAV registers its images by. `--scene [PRESET,]K=V,...`.

The camera's presets (sim_world/camera/model.py) were tuned on the scene of the same name, so a run
that names no scene gets its camera preset's: `--camera ideal` the plain floor, the realistic camera
the marked one.
"""
from __future__ import annotations

from protocol.errors import UavRobotsError
from protocol.run_spec import SceneSpec

KEYS = {
    "landmark_spacing": "cells between the surveyed landmarks the world places (0 = none, else at least 4)",
    "goal_pads": "1: goals are green pads of 0.96 cell and robots white 0.8-cell bodies, so a robot on a goal "
                 "leaves a green frame; 0: goal discs and full-cell robot tags (a robot hides its goal)",
}
PRESETS: dict[str, dict[str, int]] = {
    "ideal": {"landmark_spacing": 0, "goal_pads": 0},
    "realistic": {"landmark_spacing": 12, "goal_pads": 1},
}
MAX_SPACING = 10_000


def scene_options(text: str, preset: str = "realistic") -> SceneSpec:
    """`--scene` text -> the scene: an optional preset first (else `preset`, the camera's), then
    name=number pairs over it; one line naming the first bad part."""
    parts = [p.strip() for p in (text or "").split(",") if p.strip()]
    if parts and "=" not in parts[0]:
        preset = parts.pop(0)
        if preset not in PRESETS:
            raise UavRobotsError(f"--scene {text!r}: unknown preset {preset!r} (presets: {', '.join(PRESETS)})")
    values = dict(PRESETS[preset])
    for part in parts:
        key, _, value = (s.strip() for s in part.partition("="))
        if key not in KEYS:
            raise UavRobotsError(f"--scene {text!r}: unknown key {key!r} (keys: {', '.join(KEYS)})")
        try:
            values[key] = int(value)
        except ValueError:
            raise UavRobotsError(f"--scene {text!r}: {part!r} is not name=whole number") from None
    spacing, pads = values["landmark_spacing"], values["goal_pads"]
    if not (spacing == 0 or 4 <= spacing <= MAX_SPACING):
        raise UavRobotsError(f"--scene {text!r}: landmark_spacing {spacing} is not 0 (none) or a whole number "
                             f"of cells in [4, {MAX_SPACING}]")
    if pads not in (0, 1):
        raise UavRobotsError(f"--scene {text!r}: goal_pads is 0 or 1, not {pads}")
    return SceneSpec(landmark_spacing=spacing, goal_pads=bool(pads))
