"""`uav-robots bench camera`: the camera's cost per frame, render + encode of the survey frames, per preset.

    uav-robots bench camera [--map warehouse-450] [--robots 50] [--rounds 3] [--out bench-results]

In-process (no transport): for each survey pose of the map (the 4000x3000 drone
camera, yaw 0), one `capture_frame` (render from the true pose, degrade, encode,
pose estimate). The presets run interleaved, round after round, so a busy
machine slows them alike; the table gives medians over every frame of every
round and the ratio to `ideal` (whose output is byte-identical to the renderer
before the honest camera). One-time costs (the lens's distortion map, the noise
bank, the gain field) are measured apart, on the first frame.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

from protocol.errors import UavRobotsError

CASES = {
    "ideal": "ideal",
    "realistic": "realistic",
    "realistic, moving 5 m/s": "realistic",
}


def bench(map_spec: str, robots: int, rounds: int) -> list[dict]:
    from scenarios.maps import place, resolve_map
    from scenarios.scene import scene_options
    from sim_world.camera import PoseEstimator, Scene, VehicleView, camera_model_from, capture_frame, scene_landmarks
    from sim_world.camera.model import camera_preset
    from sim_world.config import DRONE_CAMERA
    from uav_agent.survey import survey_poses

    _, free = resolve_map(map_spec, 0)
    p = place(free, robots, 0)
    h, w = free.shape
    setups = {}
    for name, text in CASES.items():
        model = camera_model_from(text, DRONE_CAMERA)
        marks = scene_options("", camera_preset(text))
        scene = Scene(free, dict(enumerate(p.starts)), p.goals, scene_landmarks(free, 1.0, marks.landmark_spacing),
                      goal_pads=marks.goal_pads)
        poses = survey_poses(w, h, 1.0, model)
        speed = 5.0 if "moving" in name else 0.0
        t0 = time.perf_counter()
        n, e, alt = poses[0]
        capture_frame(scene, VehicleView(n, e, -alt, vel_east=speed), model, 1.0, PoseEstimator(model), 0.0)
        setups[name] = (model, scene, poses, speed, time.perf_counter() - t0)
    times: dict[str, list[float]] = {name: [] for name in CASES}
    sizes: dict[str, list[int]] = {name: [] for name in CASES}
    for r in range(rounds):
        for name, (model, scene, poses, speed, _) in setups.items():
            est = PoseEstimator(model, r)
            for i, (n, e, alt) in enumerate(poses):
                t0 = time.perf_counter()
                frame = capture_frame(scene, VehicleView(n, e, -alt, vel_east=speed), model, 1.0, est,
                                      float(i), seq=i)
                times[name].append(time.perf_counter() - t0)
                sizes[name].append(len(frame.png))
            print(f"round {r + 1}/{rounds} {name}: median {statistics.median(times[name]) * 1e3:.0f} ms",
                  file=sys.stderr, flush=True)
    base = statistics.median(times["ideal"])
    return [{"camera": name, "frames": len(times[name]), "median_ms": statistics.median(times[name]) * 1e3,
             "ratio": statistics.median(times[name]) / base, "first_frame_ms": setups[name][4] * 1e3,
             "median_bytes": statistics.median(sizes[name])} for name in CASES]


def markdown(rows: list[dict], map_spec: str, robots: int) -> str:
    lines = [f"Camera cost per frame, {map_spec} with {robots} robots, 4000x3000, survey poses "
             "(`uav-robots bench camera`)", "",
             "| camera | frames | render+encode median | vs ideal | first frame (one-time setup) | image bytes |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['camera']} | {r['frames']} | {r['median_ms']:.0f} ms | {r['ratio']:.2f} | "
                     f"{r['first_frame_ms']:.0f} ms | {r['median_bytes'] / 1e6:.1f} MB |")
    return "\n".join(lines) + "\n"


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("camera", help="the camera's cost per frame: render + encode of the survey, per preset",
                       description=__doc__.split("\n")[0])
    p.add_argument("--map", default="warehouse-450", help="the floor the survey frames show (default warehouse-450)")
    p.add_argument("--robots", type=int, default=50, help="robots on it (default 50)")
    p.add_argument("--rounds", type=int, default=3, help="rounds over every survey pose, presets interleaved (default 3)")
    p.add_argument("--out", default=None, help="directory for camera.md (default: print only)")
    return p


def run(a: argparse.Namespace) -> int:
    if a.rounds < 1 or a.robots < 1:
        raise UavRobotsError("--rounds and --robots must be at least 1")
    text = markdown(bench(a.map, a.robots, a.rounds), a.map, a.robots)
    print(text)
    if a.out:
        Path(a.out).mkdir(parents=True, exist_ok=True)
        (Path(a.out) / "camera.md").write_text(text)
    return 0
