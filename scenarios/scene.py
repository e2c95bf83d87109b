"""What the world lays on the floor besides shelves and robots, for the camera to see: how goals are
marked, the surveyed landmarks the UAV registers its images by, and the people, forklifts and pallets
that move among the robots unannounced. `--scene [PRESET,]K=V,...`; `--movers N --mover-speed S` and
`--mover-routes FILE` are its movers' keys spelt as flags.

The camera's presets (sim_world/camera/model.py) were tuned on the scene of the same name, so a run
that names no scene gets its camera preset's: `--camera ideal` the plain floor, the realistic camera
the marked one.
"""
from __future__ import annotations

from pathlib import Path

from protocol.bounds import MAX_MOVERS
from protocol.errors import UavRobotsError
from protocol.run_spec import SceneSpec

KEYS = {
    "landmark_spacing": "cells between the surveyed landmarks the world places (0 = none, else at least 4)",
    "goal_pads": "1: goals are green pads of 0.96 cell and robots white 0.8-cell bodies, so a robot on a goal "
                 "leaves a green frame; 0: goal discs and full-cell robot tags (a robot hides its goal)",
    "people": "people walking the aisles, about a cell per tick, with pauses",
    "forklifts": "forklifts of up to two cells per tick that park in an aisle for a while",
    "pallets": "dropped pallets: they stay where they lie",
    "routes": "a JSON file of scripted movers: waypoints walked in turn (docs/movers.md)",
}
MOVER_KEYS = ("people", "forklifts", "pallets")
MOVER_SPEEDS = {1: "people", 2: "forklifts"}   # --mover-speed S: the kind that moves at S cells per tick
PRESETS: dict[str, dict[str, int]] = {
    "ideal": {"landmark_spacing": 0, "goal_pads": 0},
    "realistic": {"landmark_spacing": 12, "goal_pads": 1},
}
MAX_SPACING = 10_000


def scene_options(text: str, preset: str = "realistic", movers: int = 0, mover_speed: int = 1,
                  routes: str | None = None) -> SceneSpec:
    """`--scene` text -> the scene: an optional preset first (else `preset`, the camera's), then
    name=number pairs over it (`routes=FILE` a file), then `--movers` of `--mover-speed` and
    `--mover-routes` added; one line naming the first bad part."""
    parts = [p.strip() for p in (text or "").split(",") if p.strip()]
    if parts and "=" not in parts[0]:
        preset = parts.pop(0)
        if preset not in PRESETS:
            raise UavRobotsError(f"--scene {text!r}: unknown preset {preset!r} (presets: {', '.join(PRESETS)})")
    values: dict[str, int] = {**PRESETS[preset], **dict.fromkeys(MOVER_KEYS, 0)}
    for part in parts:
        key, _, value = (s.strip() for s in part.partition("="))
        if key not in KEYS:
            raise UavRobotsError(f"--scene {text!r}: unknown key {key!r} (keys: {', '.join(KEYS)})")
        if key == "routes":
            routes = routes or value
            continue
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
    if mover_speed not in MOVER_SPEEDS:
        raise UavRobotsError(f"--mover-speed {mover_speed}: 1 (people) or 2 (forklifts) cells per tick")
    if movers:
        values[MOVER_SPEEDS[mover_speed]] += movers
    for key in MOVER_KEYS:
        if not 0 <= values[key] <= MAX_MOVERS:
            raise UavRobotsError(f"--scene {text!r}: {key} {values[key]} is not in [0, {MAX_MOVERS}]")
    if sum(values[k] for k in MOVER_KEYS) > MAX_MOVERS:
        raise UavRobotsError(f"at most {MAX_MOVERS} movers on one floor")
    if routes is not None and not Path(routes).is_file():
        raise UavRobotsError(f"--mover-routes {routes}: no such file")
    return SceneSpec(landmark_spacing=spacing, goal_pads=bool(pads), routes=routes,
                     **{k: values[k] for k in MOVER_KEYS})


def add_mover_arguments(p) -> None:
    """The scene's movers as flags (`run` and `world` alike)."""
    p.add_argument("--movers", type=int, default=0, metavar="N",
                   help="N uncooperative movers on the floor, placed by the seed: people walking the aisles "
                        "(--mover-speed 1) or forklifts (2); more kinds, pallets too, with --scene people=,forklifts=,pallets=")
    p.add_argument("--mover-speed", type=int, default=1, choices=sorted(MOVER_SPEEDS), metavar="S",
                   help="cells per tick of the --movers: 1 people (default), 2 forklifts")
    p.add_argument("--mover-routes", default=None, metavar="FILE",
                   help="a JSON file of scripted movers: routes of waypoints, pallets dropped at a tick (docs/movers.md)")


def scene_of_args(args, preset: str) -> SceneSpec:
    """`--scene` with the mover flags over it."""
    return scene_options(args.scene, preset, args.movers, args.mover_speed, args.mover_routes)
