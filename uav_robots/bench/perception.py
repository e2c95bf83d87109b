"""`uav-robots bench perception`: perception's accuracy and time under degraded cameras.

Offline and in-process: the world's camera (sim_world.camera) renders what the
UAV would see on the mission's own survey, the UAV's perception reads it, and
the result is scored against the scene. The survey follows the mission's rules
(one image first; if its measured blur needs it, a lower survey; then up to two
rounds of closer looks at what perception left in doubt), so an error here is
an error the mission would meet. Hover poses are exact (the vehicle settles);
the published pose is the camera's estimate with its stated error.

Cases: each degradation axis alone from the realistic preset (blur sigma,
lighting, noise, pose error, yaw error) and the combined target, on three maps.
Columns: cells wrong (misread or unseen), robots missed or misplaced, goals
missed or invented, images, perception seconds (reading only, rendering not counted).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from protocol.errors import UavRobotsError
from protocol.run_spec import SceneSpec
from scenarios.maps import place, resolve_map
from scenarios.scene import scene_options
from sim_world.camera import PRESETS, CameraModel, PoseEstimator, Scene, VehicleView, capture_frame, scene_landmarks
from sim_world.config import DRONE_CAMERA
from uav_agent.mission import MissionConfig
from uav_agent.mission.looks import border as survey_border
from uav_agent.perception import Landmarks, decode_frame, perceive
from uav_agent.perception.blur import blur_sigma
from uav_agent.perception.frames import undistorted
from uav_agent.perception.relook import ROUNDS, plan_round
from uav_agent.survey import ROBOT_MODULE_CELLS, px_per_cell_for, survey_poses

# map: (spec, robots, every axis or only the realistic and target cases). Every map is read by the
# world's 4000x3000 drone camera, as its mission is; the 450 warehouse only at the two cases that
# matter: one costs minutes.
MAPS = {"default": ("warehouse-small", 8, True),
        "warehouse-450": ("warehouse-450", 50, False),
        "random-64": ("random:width=64,height=64,density=0.2", 20, True)}
# A camera with a tenth of the drone camera's pixels: its footprints at the resolution markers
# need are a few landmark spacings across, so it shows where registration runs short of landmarks.
SMALL_CAMERA = {"width": 1280, "height": 960}
TARGET = {"blur_sigma": 2.0, "lighting": 0.5, "noise_std": 10.0, "pose_sigma_m": 0.5, "yaw_sigma_deg": 3.0}
AXES: dict[str, list[float]] = {"blur_sigma": [0.0, 1.0, 2.0, 3.0], "lighting": [0.3, 0.5, 0.7, 0.85],
                                "noise_std": [0.0, 10.0, 20.0], "pose_sigma_m": [0.0, 0.5, 1.0],
                                "yaw_sigma_deg": [0.0, 3.0, 5.0]}
MIN_PX_PER_CELL = MissionConfig.min_px_per_cell   # the mission's own survey resolution
CELL = 1.0


@dataclass
class Row:
    map: str
    case: str
    cells_wrong: int
    robots_wrong: int
    goals_wrong: int
    unsure: int
    images: int
    registered: str           # frames placed by landmarks / all
    perception_s: float
    error: str = ""


def bench_scene(spec: str, robots: int, marks: SceneSpec | None = None) -> Scene:
    """The floor `spec` with `robots` placed, laid out as the realistic scene (or `marks`)."""
    marks = marks or scene_options("", "realistic")
    _, free = resolve_map(spec, 0)
    p = place(free, robots, 1)
    return Scene(free, {(i * 37 + 3) % 1000: c for i, c in enumerate(p.starts)}, p.goals,
                 scene_landmarks(free, CELL, marks.landmark_spacing), goal_pads=marks.goal_pads)


def landmarks_of(scene: Scene) -> Landmarks | None:
    """The scene's landmarks as the UAV knows them from WorldInfo."""
    if scene.landmarks is None:
        return None
    lm = scene.landmarks
    by_id: dict[int, list] = {}
    for lid, e, n in lm.landmarks:
        by_id.setdefault(lid, []).append((e, n))
    return Landmarks(lm.family, lm.size_m, {k: np.array(v) for k, v in by_id.items()})


def simulate(scene: Scene, model: CameraModel, seed: int = 0, survey_tilt_deg: float = 0.0):
    """The mission's survey and closer looks, rendered offline: (world model, images, perception seconds).
    `survey_tilt_deg`: the survey's images are taken leaning this much (roll or pitch, either
    way, image by image), as a body-fixed camera is right after the vehicle brakes; the closer
    looks wait for a level body, as the mission's do."""
    h, w = scene.free.shape
    marks = landmarks_of(scene)
    estimator = PoseEstimator(model, seed)
    frames, clock, spent = [], [0.0], [0.0]

    def shoot(n: float, e: float, alt: float, tilt: float = 0.0):
        clock[0] += 2.0                                   # seconds of flight between images, for the estimate's drift
        k = len(frames)
        lean = (tilt if k % 2 else -tilt, 0.0) if k % 4 < 2 else (0.0, tilt if k % 2 else -tilt)
        frames.append(capture_frame(scene, VehicleView(n, e, -alt, 0.0, *lean), model, CELL, estimator, clock[0], k))
        return frames[-1]

    tilt = math.radians(survey_tilt_deg)

    def timed(fn, *a, **k):
        t = time.perf_counter()
        out = fn(*a, **k)
        spent[0] += time.perf_counter() - t
        return out

    border = survey_border(model, MIN_PX_PER_CELL, CELL)   # the mission's (the model has the frame's lens fields)
    poses = survey_poses(w, h, CELL, model, min_px_per_cell=MIN_PX_PER_CELL, border_px=border)
    first = shoot(*poses[0], tilt)

    def need_ppc():
        image, _ = undistorted(decode_frame(first))
        import cv2
        sigma = blur_sigma(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
        module = ROBOT_MODULE_CELLS if marks is None else min(ROBOT_MODULE_CELLS, marks.module_m / CELL)
        return px_per_cell_for(sigma, MIN_PX_PER_CELL, module)

    ppc = timed(need_ppc)
    if ppc > MIN_PX_PER_CELL:
        poses = survey_poses(w, h, CELL, model, min_px_per_cell=ppc, border_px=survey_border(model, ppc, CELL))
        for p in poses:
            shoot(*p, tilt)
    else:
        for p in poses[1:]:
            shoot(*p, tilt)
    survey_alt = max(p[2] for p in poses)
    known = set(scene.robots)
    wm = timed(perceive, frames, w, h, CELL, known_ids=known, landmarks=marks)
    here = poses[-1][:2]
    for attempt in range(1, ROUNDS + 1):
        cells, hovers = plan_round(wm, known, True, attempt, survey_alt, CELL, model, marks, here,
                                   survey_images=len(poses))
        if not cells:
            break
        for n, e, alt in hovers:
            shoot(n, e, alt)
        here = hovers[-1][:2]
        wm = timed(perceive, frames, w, h, CELL, known_ids=known, landmarks=marks)
    return wm, len(frames), spent[0]


def score(wm, scene: Scene) -> tuple[int, int, int]:
    cells = int((wm.free != scene.free).sum())
    robots = sum(wm.robots.get(r) != c for r, c in scene.robots.items()) + len(set(wm.robots) - set(scene.robots))
    goals = len(set(scene.goals) ^ set(wm.goals))
    return cells, robots, goals


def cases(full: bool) -> list[tuple[str, dict[str, float]]]:
    out = [("realistic", {}), ("target: " + ", ".join(f"{k}={v:g}" for k, v in TARGET.items()), dict(TARGET))]
    if full:
        for key, values in AXES.items():
            out += [(f"{key}={v:g}", {key: v}) for v in values]
    return out


def run_case(name: str, spec: str, robots: int, label: str, over: dict[str, float], camera: dict[str, Any],
             survey_tilt_deg: float = 0.0) -> Row:
    try:
        model = CameraModel(**{**camera, **PRESETS["realistic"], **over})
        scene = bench_scene(spec, robots)
        wm, images, seconds = simulate(scene, model, survey_tilt_deg=survey_tilt_deg)
        c, r, g = score(wm, scene)
        reg = sum(f.source == "landmarks" for f in wm.frames)
        return Row(name, label, c, r, g, len(wm.unsure), images, f"{reg}/{len(wm.frames)}", round(seconds, 2))
    except UavRobotsError as exc:       # a clear failure is a result; a traceback is a bug
        return Row(name, label, -1, -1, -1, -1, 0, "", 0.0, str(exc).splitlines()[0])


def markdown(rows: list[Row]) -> str:
    head = ["map", "case", "cells wrong", "robots missed/misplaced", "goals missed/invented", "unsure", "images",
            "registered", "perception s", "error"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join(str(v) for v in (r.map, r.case, r.cells_wrong, r.robots_wrong, r.goals_wrong,
                                                          r.unsure, r.images, r.registered, r.perception_s,
                                                          r.error)) + " |")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.survey_tilt) and 0 <= args.survey_tilt <= 30):
        raise UavRobotsError(f"bench perception: --survey-tilt must be 0..30 degrees, got {args.survey_tilt}")
    names = [m.strip() for m in args.maps.split(",") if m.strip()]
    for m in names:
        if m not in MAPS:
            raise UavRobotsError(f"bench perception: unknown map {m!r} (maps: {', '.join(MAPS)})")
    rows: list[Row] = []
    for m in names:
        spec, robots, every_axis = MAPS[m]
        camera = dict(SMALL_CAMERA) if args.small_camera else dict(DRONE_CAMERA)
        for label, over in cases(every_axis and not args.quick):
            row = run_case(m, spec, robots, label, over, camera, args.survey_tilt)
            rows.append(row)
            print(f"{m:14s} {label:70s} cells {row.cells_wrong:5d} robots {row.robots_wrong:3d} goals "
                  f"{row.goals_wrong:3d} unsure {row.unsure:4d} images {row.images:3d} reg {row.registered:7s} "
                  f"{row.perception_s:6.2f}s {row.error}", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = (f"# Perception under degraded cameras\n\n`uav-robots bench perception --maps {args.maps}"
            f"{' --quick' if args.quick else ''}{' --small-camera' if args.small_camera else ''}"
            f"{f' --survey-tilt {args.survey_tilt:g}' if args.survey_tilt else ''}`: offline, "
            f"in-process; realistic preset plus the case's keys; image "
            f"{'1280x960 (not the mission camera)' if args.small_camera else '4000x3000, the mission camera'}"
            f".\n\n" + markdown(rows))
    (out / "perception.md").write_text(text)
    (out / "perception.json").write_text(json.dumps({"format": "uav-robots-bench-perception/1",
                                                     "rows": [asdict(r) for r in rows]}, indent=1))
    print(f"wrote {out / 'perception.md'} and perception.json")
    bad = [r for r in rows if (r.case == "realistic" or r.case.startswith("target")) and
           (r.error or r.cells_wrong or r.robots_wrong or r.goals_wrong)]
    return 1 if bad else 0


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("perception", help="perception accuracy under degraded cameras (offline)",
                       description="Renders the mission's survey offline for each camera degradation and scores "
                                   "perception: cells wrong, robots and goals missed, perception time.")
    p.add_argument("--maps", default="default,warehouse-450,random-64", help=f"comma-separated: {', '.join(MAPS)}")
    p.add_argument("--quick", action="store_true", help="only the realistic preset and the combined target")
    p.add_argument("--small-camera", action="store_true",
                   help="a 1280x960 camera instead of the mission's 4000x3000 one: a tenth of the pixels, "
                        "so surveys fly low and see few landmarks per image")
    p.add_argument("--survey-tilt", type=float, default=0.0, metavar="DEG",
                   help="survey images taken leaning this much (roll or pitch), as a body-fixed camera is right "
                        "after the vehicle brakes; closer looks wait for a level body (default 0)")
    p.add_argument("--out", default="bench-out", help="directory for perception.md and perception.json")
    return p
