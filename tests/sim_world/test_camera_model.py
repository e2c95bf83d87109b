"""The honest camera: pose estimate, lens distortion, motion blur, JPEG, attitude, presets.

Images are really rendered and read back through OpenCV (ArUco detection,
undistortPoints, imdecode); the vehicle's attitude goes over real MAVLink.
"""
from __future__ import annotations

import hashlib
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest

from protocol.errors import UavRobotsError
from protocol.run_spec import SceneSpec
from scenarios.landmarks import place_landmarks
from scenarios.maps import place, resolve_map
from sim_world.camera import (DEFAULT_CAMERA_PRESET, KEYS, PRESETS, CameraModel, PoseEstimator, Scene, VehicleView,
                              camera_model_from, camera_options, capture_frame, floor_homography, render)
from sim_world.vehicle.dynamics import MAX_TILT_DEG, Contact, Dynamics
from sim_world.vehicle.motion import Setpoint
from sim_world.vehicle.journal import Journal

CELL = 1.0


def _scene(spec: str = "warehouse:blocks_x=3,blocks_y=6", robots: int = 6, landmarks: bool = True) -> Scene:
    _, free = resolve_map(spec, 0)
    p = place(free, robots, 0)
    return Scene(free, dict(enumerate(p.starts)), p.goals, place_landmarks(free, CELL) if landmarks else None)


def _detect(image: np.ndarray, family: str = "DICT_5X5_1000") -> dict[int, np.ndarray]:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family)), params)
    corners, ids, _ = det.detectMarkers(image)
    return {} if ids is None else {int(i): c[0] for i, c in zip(ids.ravel(), corners)}


def _true_corners(scene: Scene, pose, model: CameraModel) -> dict[int, np.ndarray]:
    """Pinhole projections of every landmark's corners (OpenCV's order, top = north)."""
    H = floor_homography(pose, model, CELL)
    s = scene.landmarks.size_m / 2
    out = {}
    for lid, e, n in scene.landmarks.landmarks:
        quad = np.array([[[e - s, -(n + s)]], [[e + s, -(n + s)]], [[e + s, -(n - s)]], [[e - s, -(n - s)]]]) / CELL
        out[lid] = cv2.perspectiveTransform(quad, H).reshape(-1, 2)
    return out


# --- today's camera, unchanged ---------------------------------------------------------

# sha256 prefixes of renders by the renderer before this change (commit fce4b10), on OpenCV 5.0.0.
GOLDEN = {(-9.0, 12.0, -10.0, 0.3): "7b0a4cb1af9980c4", (-4.0, 3.0, -3.0, -2.0): "f8f2da13a165e86d",
          (-9.0, 12.0, -14.0, 0.0): "d398b8c002dd13d8"}


@pytest.mark.skipif(cv2.__version__ != "5.0.0", reason="the reference hashes were taken with OpenCV 5.0.0")
def test_the_ideal_camera_renders_byte_identically_to_the_previous_renderer():
    _, free = resolve_map("warehouse-small")
    p = place(free, 8, 0)
    scene = Scene(free, dict(enumerate(p.starts)), p.goals)   # no landmarks: the old world had none
    model = camera_model_from("ideal,width=640,height=480")
    assert model == CameraModel(width=640, height=480)
    for pose, digest in GOLDEN.items():
        assert hashlib.sha256(render(scene, pose, model, CELL).tobytes()).hexdigest()[:16] == digest, pose


def test_the_ideal_frame_publishes_the_true_pose_as_png():
    scene, model = _scene(), CameraModel(width=640, height=480)
    view = VehicleView(-8.0, 10.0, -12.0, 0.4)
    frame = capture_frame(scene, view, model, CELL, PoseEstimator(model, 3), 5.0, seq=1)
    assert (frame.north_m, frame.east_m, frame.down_m, frame.yaw_rad) == view[:4]
    assert frame.encoding == "png" and frame.pose_sigma_m == 0 and frame.k1 == 0 and frame.roll_rad == 0
    image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(image, render(scene, view[:4], model, CELL, seed=1))


# --- the pose is an estimate -------------------------------------------------------------

def test_the_published_pose_errs_with_the_configured_statistics_and_is_seeded():
    model = CameraModel(pose_sigma_m=0.2, yaw_sigma_deg=1.5, attitude_sigma_deg=0.3)
    truth = (-20.0, 30.0, -15.0, 0.5, 0.01, -0.02)

    def errors(seed: int, step_s: float, n: int) -> np.ndarray:
        est = PoseEstimator(model, seed)
        out = []
        for i in range(n):
            p = est.estimate(truth, i * step_s)
            dyaw = (p.yaw_rad - truth[3] + math.pi) % (2 * math.pi) - math.pi
            out.append((p.north_m - truth[0], p.east_m - truth[1], p.down_m - truth[2], math.degrees(dyaw),
                        math.degrees(p.roll_rad - truth[4]), math.degrees(p.pitch_rad - truth[5])))
        return np.array(out)

    far = errors(1, 300.0, 3000)   # 10 bias time constants apart: independent draws
    std = far.std(axis=0)
    assert std[0] == pytest.approx(0.2, rel=0.1) and std[1] == pytest.approx(0.2, rel=0.1)
    assert std[2] == pytest.approx(0.05, rel=0.1)
    assert std[3] == pytest.approx(1.5, rel=0.1) and std[4] == pytest.approx(0.3, rel=0.1)
    assert np.abs(far.mean(axis=0)[:2]).max() < 0.03
    # Frames a second apart share the drifting bias: their errors are strongly correlated.
    near = errors(2, 1.0, 400)
    assert np.corrcoef(near[:-1, 0], near[1:, 0])[0, 1] > 0.6
    assert np.array_equal(errors(7, 1.0, 20), errors(7, 1.0, 20))
    assert not np.array_equal(errors(7, 1.0, 20), errors(8, 1.0, 20))


def test_the_frame_states_its_sigmas_and_carries_the_estimate_not_the_truth():
    scene = _scene()
    model = CameraModel(width=640, height=480, pose_sigma_m=0.5, yaw_sigma_deg=3.0)
    view = VehicleView(-8.0, 10.0, -12.0, 0.0)
    frame = capture_frame(scene, view, model, CELL, PoseEstimator(model, 0), 1.0)
    assert (frame.pose_sigma_m, frame.yaw_sigma_deg) == (0.5, 3.0)
    assert (frame.north_m, frame.east_m) != (view.north_m, view.east_m)
    # The image itself is taken from the truth.
    image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(image, render(scene, view.pose, model, CELL, seed=0))


# --- optics ------------------------------------------------------------------------------

@pytest.mark.parametrize("k", [(-0.05, 0.01, 0.0003, -0.0002, 0.0), (0.08, -0.02, 0.0, 0.001, 0.005)])
def test_undistorting_a_rendered_landmark_corner_with_the_published_coefficients_gives_the_pinhole_point(k):
    scene = _scene()
    h, w = scene.free.shape
    model = CameraModel(width=1600, height=1200, k1=k[0], k2=k[1], p1=k[2], p2=k[3], k3=k[4])
    pose = (-h / 2 - 3, w / 2 + 2, -13.0, 0.3)
    frame = capture_frame(scene, VehicleView(*pose), model, CELL, PoseEstimator(model), 0.0)
    assert (frame.k1, frame.k2, frame.p1, frame.p2, frame.k3) == k
    image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_COLOR)
    found = _detect(image)
    # The same view through an ideal lens: ArUco's own corner bias (~0.5 px) cancels in the comparison.
    pinhole = _detect(render(scene, pose, CameraModel(width=1600, height=1200), CELL))
    truth = _true_corners(scene, pose, model)
    assert len(set(found) & set(pinhole)) >= 6
    K = np.array([[frame.fx, 0, frame.cx], [0, frame.fy, frame.cy], [0, 0, 1]])
    D = np.array([frame.k1, frame.k2, frame.p1, frame.p2, frame.k3])
    worst_raw = worst = worst_truth = 0.0
    for lid in set(found) & set(pinhole):
        quad = found[lid]
        und = cv2.undistortPoints(quad.reshape(-1, 1, 2).astype(np.float64), K, D, P=K).reshape(-1, 2)
        worst = max(worst, float(np.abs(und - pinhole[lid]).max()))
        worst_truth = max(worst_truth, float(np.abs(und - truth[lid]).max()))
        worst_raw = max(worst_raw, float(np.abs(quad - truth[lid]).max()))
    assert worst < 0.5, f"undistorted corners off the pinhole image's by {worst:.2f} px"
    assert worst_truth < 1.0, f"undistorted corners off the pinhole projection by {worst_truth:.2f} px"
    assert worst_raw > 3, "the lens should visibly bend the image"


def test_the_camera_renders_through_the_vehicles_attitude():
    scene = _scene()
    h, w = scene.free.shape
    model = CameraModel(width=1600, height=1200)
    for roll, pitch in ((0.08, 0.0), (0.0, -0.1), (0.05, 0.07)):
        pose = (-h / 2, w / 2, -14.0, 0.2, roll, pitch)
        found = _detect(render(scene, pose, model, CELL))
        truth = _true_corners(scene, pose, model)
        level = _true_corners(scene, pose[:4], model)
        assert len(found) >= 6
        err = max(float(np.abs(q - truth[i]).max()) for i, q in found.items())
        shift = max(float(np.abs(level[i] - truth[i]).max()) for i in found)
        assert err < 1.0 and shift > 50, (roll, pitch, err, shift)
    # Nose down (accelerating forward) the camera looks back: the scene moves up the image.
    level = _true_corners(scene, (-h / 2, w / 2, -14.0), model)
    nose_down = _true_corners(scene, (-h / 2, w / 2, -14.0, 0.0, 0.0, -0.1), model)
    some = next(iter(level))
    assert nose_down[some][0, 1] < level[some][0, 1] - 100


def _sharpness(image: np.ndarray, axis: int) -> float:
    """Gradient energy along an axis: a smear along it spreads each edge and lowers it."""
    g = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float32)
    return float((np.diff(g, axis=axis) ** 2).mean())


def test_motion_blur_appears_only_when_moving_and_along_the_motion():
    scene = _scene(landmarks=True)
    h, w = scene.free.shape
    model = CameraModel(width=1200, height=900, exposure_ms=20.0)
    pose = (-h / 2, w / 2, -12.0, 0.0)
    still = render(scene, pose, model, CELL)
    assert np.array_equal(still, render(scene, pose, CameraModel(width=1200, height=900), CELL))
    east = render(scene, pose, model, CELL, velocity_ned=(0.0, 6.0, 0.0))   # yaw 0: image x, 6 px
    north = render(scene, pose, model, CELL, velocity_ned=(6.0, 0.0, 0.0))  # image y
    assert not np.array_equal(east, still)
    # Along the smear, edges soften much more than across it.
    assert _sharpness(east, 1) < 0.5 * _sharpness(still, 1) and _sharpness(east, 0) > 0.8 * _sharpness(still, 0)
    assert _sharpness(north, 0) < 0.5 * _sharpness(still, 0) and _sharpness(north, 1) > 0.8 * _sharpness(still, 1)


def test_jpeg_frames_decode_close_to_the_lossless_image():
    scene = _scene()
    model = CameraModel(width=800, height=600, jpeg_quality=90, vignetting=0.3, noise_std=3.0)
    view = VehicleView(-10.0, 12.0, -12.0)
    frame = capture_frame(scene, view, model, CELL, PoseEstimator(model), 0.0, seq=4)
    assert frame.encoding == "jpeg" and frame.png[:2] == b"\xff\xd8"
    image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_COLOR)
    exact = render(scene, view.pose, model, CELL, seed=4)
    assert image.shape == exact.shape and np.abs(image.astype(int) - exact).mean() < 4.0
    assert len(frame.png) < len(cv2.imencode(".png", exact)[1])


def test_vignetting_darkens_the_corners_not_the_centre():
    scene = Scene(np.ones((40, 40), bool))
    model = CameraModel(width=400, height=300, vignetting=0.4)
    image = render(scene, (-20.0, 20.0, -5.0), model, CELL).astype(float)
    assert image[150, 200].mean() == pytest.approx(215, abs=1)
    assert image[0, 0].mean() == pytest.approx(215 * 0.6, abs=2)


# --- attitude -----------------------------------------------------------------------------

class _Pilot:
    """Flies a list of (target, until_s) legs; a scripted stand-in beside the real autopilot."""

    def __init__(self, legs):
        self.legs, self.t = legs, 0.0

    def setpoint(self, dt, wall_now):
        self.t += dt
        target = next((tgt for tgt, until in self.legs if self.t < until), self.legs[-1][0])
        return Setpoint(target=target, yaw=0.0, speed_xy=12.0, speed_up=3.0, speed_down=1.0)

    def on_moved(self, setpoint):
        pass

    def on_contact(self, contact: Contact | None):
        pass


def _fly(wobble_deg: float, seed: int = 0):
    import threading
    lock = threading.RLock()
    dyn = Dynamics(lock, Journal(lock, sim_time=lambda: 0.0), ceiling=lambda: 120.0, wobble_deg=wobble_deg, seed=seed)
    pilot = _Pilot([((0.0, 0.0, -10.0), 5.0), ((40.0, 0.0, -10.0), 12.0), ((40.0, 30.0, -10.0), 30.0)])
    trace = []
    for _ in range(int(30 / 0.02)):
        dyn.step(0.02, 0.0, pilot)
        s = dyn.state()
        trace.append((pilot.t, s.pos, math.degrees(s.roll), math.degrees(s.pitch)))
    return trace


def test_the_vehicle_tilts_while_accelerating_and_only_wobbles_at_rest():
    trace = _fly(0.0)
    at = {round(t, 2): (pos, roll, pitch) for t, pos, roll, pitch in trace}
    # North from t = 5 s: nose down while speeding up, nose up while stopping (at 40/12 s later).
    assert min(p for t, _, _, p in trace if 5.0 <= t < 5.5) < -10
    assert min(p for t, _, _, p in trace if 5.0 <= t < 5.5) >= -MAX_TILT_DEG - 1e-9
    assert max(p for t, _, _, p in trace if 8.3 <= t < 9.0) > 10
    # East from t = 12 s: roll right while speeding up.
    assert max(r for t, _, r, _ in trace if 12.0 <= t < 12.5) > 10
    # Cruising at constant velocity and hovering: level.
    assert abs(at[7.0][2]) < 0.05 and abs(at[11.0][1]) < 0.05 and abs(at[29.0][1]) < 0.05
    wobbly = _fly(0.3, seed=1)
    rest = np.array([(r, p) for t, _, r, p in wobbly if 20.0 <= t < 30.0])
    assert np.abs(rest).max() <= 0.3 + 1e-9 and rest.std(axis=0).min() > 0.05
    assert np.array_equal(rest, np.array([(r, p) for t, _, r, p in _fly(0.3, seed=1) if 20.0 <= t < 30.0]))
    ground = np.array([(r, p) for t, pos, r, p in wobbly if t < 0.03])
    assert not ground.any(), "no wobble on the ground"


def test_the_vehicle_reports_its_attitude_over_mavlink():
    from mavlink_gcs import Client
    from pymavlink.dialects.v20 import common as mavlink
    from sim_world.vehicle import Vehicle, VehicleConfig

    v = Vehicle(VehicleConfig(url="udpin:127.0.0.1:0", time_scale=5.0, hover_wobble_deg=0.5, seed=3)).start()
    client = Client(v.local_address[1])
    try:
        client.recv("HEARTBEAT")
        assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
        assert client.command(mavlink.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7) == mavlink.MAV_RESULT_ACCEPTED
        client.recv("GLOBAL_POSITION_INT", timeout=10, cond=lambda m: m.relative_alt > 2_000)  # MIS_TAKEOFF_ALT, 2.5 m
        msgs = [client.recv("ATTITUDE") for _ in range(20)]
        rolls = [m.roll for m in msgs]
        assert max(abs(r) for r in rolls) <= math.radians(0.5) + 1e-6
        assert len(set(rolls)) > 5, "the hover wobble shows in ATTITUDE"
        s = v.state()
        assert abs(s.roll) <= math.radians(0.5) + 1e-6
    finally:
        client.close()
        v.stop()


# --- presets and keys -----------------------------------------------------------------

def test_presets_and_keys_combine_and_every_key_has_a_default():
    assert DEFAULT_CAMERA_PRESET == "realistic" and camera_options("") == PRESETS["realistic"]
    assert camera_options("ideal") == {} and camera_model_from("ideal") == CameraModel()
    real = camera_model_from("realistic")
    assert (real.pose_sigma_m, real.yaw_sigma_deg, real.k1, real.jpeg_quality) == (0.2, 1.5, -0.05, 90)
    assert real.noise_std == 3.0 and real.exposure_ms == 4.0 and real.vignetting > 0 and real.gimbal == 0
    mixed = camera_model_from("realistic,blur_sigma=2,jpeg_quality=0")
    assert mixed.blur_sigma == 2 and mixed.jpeg_quality == 0 and mixed.k1 == -0.05
    assert camera_model_from("blur_sigma=1.5") == CameraModel(**{**PRESETS["realistic"], "blur_sigma": 1.5})  # over the default
    assert camera_model_from("ideal,blur_sigma=1.5") == CameraModel(blur_sigma=1.5)
    model_fields = set(CameraModel.__dataclass_fields__)
    assert set(KEYS) == model_fields and set(PRESETS["realistic"]) <= model_fields
    for key, (default, _) in KEYS.items():
        if default is not None:
            assert getattr(CameraModel(), key) == default, key


@pytest.mark.parametrize("text, words", [
    ("fisheye", "unknown preset"),
    ("blur_sigma=1,realistic", "a preset comes first"),
    ("zoom=3", "unknown key"),
    ("jpeg_quality=101", "jpeg_quality"),
    ("jpeg_quality=50.5", "jpeg_quality"),
    ("vignetting=1", "vignetting"),
    ("k1=0.9,k2=-1", "folds"),
    ("pose_sigma_m=-1", "pose_sigma_m"),
    ("exposure_ms=nan", "finite"),
    ("landmark_spacing=12", "not the camera's but the scene's: --scene landmark_spacing=N"),
    ("goal_pads=1", "the scene's"),
    ("realistic,wobble_deg=1", "not the camera's but the vehicle's: --wobble DEG"),
])
def test_bad_camera_values_are_one_line_errors(text, words):
    with pytest.raises(UavRobotsError, match=words):
        camera_model_from(text, {"width": 4000, "height": 3000})


@pytest.mark.parametrize("command", [["uav_robots", "run"], ["sim_world", "--mavlink", "none"]])
@pytest.mark.process
def test_bad_camera_values_stop_run_and_the_world_before_anything_starts(command):
    run = subprocess.run([sys.executable, "-m", *command, "--camera", "realistic,jpeg_quality=300"],
                         capture_output=True, text=True, timeout=60)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and run.stdout == "" and len(lines) == 1 and "jpeg_quality" in lines[0], lines


# --- a robot on its goal ------------------------------------------------------------------

def _green(image: np.ndarray) -> np.ndarray:
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    return cv2.inRange(hsv, (45, 110, 110), (75, 255, 255)) > 0


@pytest.mark.parametrize("yaw", [0.0, 0.6])
def test_a_robot_on_a_goal_leaves_a_green_frame_around_its_readable_marker(yaw):
    free = np.ones((8, 10), bool)
    on_goal, beside = (3, 3), (6, 4)
    scene = Scene(free, {5: on_goal, 17: beside}, [on_goal, (7, 6)], goal_pads=True)
    model = CameraModel(width=1000, height=800)
    pose = (-4.0, 5.0, -5.0, yaw)
    image = render(scene, pose, model, CELL)
    found = _detect(image, "DICT_4X4_1000")
    assert set(found) == {5, 17}
    H = floor_homography(pose, model, CELL)
    green = _green(image)

    def fraction(cell, r_in: float, r_out: float) -> float:
        """Green share of the image pixels whose floor point lies in the square ring (r_in, r_out)."""
        ys, xs = np.mgrid[0:model.height, 0:model.width]
        floor = cv2.perspectiveTransform(np.stack([xs, ys], -1).reshape(-1, 1, 2).astype(np.float64),
                                         np.linalg.inv(H)).reshape(model.height, model.width, 2)
        d = np.maximum(np.abs(floor[..., 0] - cell[0] - 0.5), np.abs(floor[..., 1] - cell[1] - 0.5))
        ring = (d > r_in) & (d < r_out)
        return float(green[ring].mean())

    assert fraction(on_goal, 0.41, 0.47) > 0.95          # the frame between body (0.4) and pad (0.48)
    assert fraction(on_goal, 0.0, 0.39) < 0.01           # the body hides the rest of the pad
    assert fraction(beside, 0.41, 0.47) < 0.01           # a robot off any goal: floor around it
    assert fraction((7, 6), 0.0, 0.47) > 0.95            # a free goal: the whole pad
    # The marker is as large as the body allows: 6/7 of the 0.8-cell body.
    side = np.linalg.norm(found[5][0] - found[5][1]) / (model.fx / 5.0)
    assert side == pytest.approx(0.8 * 6 / 7, abs=0.03)


def test_a_scene_not_named_is_the_camera_presets_namesake():
    from protocol.run_spec import SceneSpec
    from scenarios.scene import scene_options
    from sim_world.camera.model import camera_preset

    assert camera_preset("") == camera_preset("blur_sigma=2") == "realistic" and camera_preset("ideal,k1=0.1") == "ideal"
    assert scene_options("", camera_preset("")) == SceneSpec(landmark_spacing=12, goal_pads=True)
    assert scene_options("", camera_preset("ideal")) == SceneSpec(landmark_spacing=0, goal_pads=False)
    assert scene_options("ideal,landmark_spacing=8", "realistic") == SceneSpec(landmark_spacing=8, goal_pads=False)
    spec = SceneSpec(landmark_spacing=20, goal_pads=False)
    assert scene_options(spec.text(), "realistic") == spec


@pytest.mark.parametrize("text, words", [
    ("marble", "unknown preset 'marble'"), ("landmark_spacing=2", "landmark_spacing 2 is not 0"),
    ("goal_pads=2", "goal_pads is 0 or 1"), ("shelves=3", "unknown key 'shelves'"),
    ("landmark_spacing=1.5", "not name=whole number"),
])
def test_bad_scene_values_are_one_line_errors(text, words):
    from scenarios.scene import scene_options

    with pytest.raises(UavRobotsError, match=words):
        scene_options(text)


def test_a_gimballed_camera_stays_level_and_a_body_fixed_one_tilts_with_the_vehicle():
    scene = _scene()
    tilted = VehicleView(-8.0, 10.0, -12.0, 0.2, 0.06, -0.04)
    level = VehicleView(-8.0, 10.0, -12.0, 0.2)
    gimballed = CameraModel(width=640, height=480)
    assert gimballed.gimbal == 1
    a = capture_frame(scene, tilted, gimballed, CELL, PoseEstimator(gimballed), 0.0)
    b = capture_frame(scene, level, gimballed, CELL, PoseEstimator(gimballed), 0.0)
    assert a == b and a.roll_rad == 0.0
    fixed = CameraModel(width=640, height=480, gimbal=0)
    c = capture_frame(scene, tilted, fixed, CELL, PoseEstimator(fixed), 0.0)
    assert (c.roll_rad, c.pitch_rad) == (0.06, -0.04) and c.png != a.png


def test_the_readme_documents_every_camera_key_with_its_default():
    from pathlib import Path
    readme = (Path(__file__).resolve().parents[2] / "docs" / "camera-and-perception.md").read_text()
    for key, (default, _) in KEYS.items():
        row = next((line for line in readme.splitlines() if line.startswith(f"| `{key}` |")), None)
        assert row is not None, f"docs/camera-and-perception.md has no row for --camera key {key}"
        if default is not None and key not in ("width", "height"):
            assert row.split("|")[2].strip() == str(default), row


def test_a_realistic_world_serves_jpeg_frames_with_an_estimated_pose_and_its_landmarks():
    from protocol.codec import decode, encode
    from protocol.messages import CameraFrame, CameraRequest, WorldInfo, WorldInfoRequest
    from protocol.transport import MemoryBus, MemoryTransport
    from sim_world.config import WorldConfig
    from sim_world.service import World

    bus = MemoryBus()
    camera = {**camera_options("realistic"), "width": 1200, "height": 900}
    world = World(WorldConfig(fleet="t", robots=4, mavlink=None, camera=camera, scene=SceneSpec(), seed=5),
                  MemoryTransport(bus))
    world.start()
    client = MemoryTransport(bus)
    try:
        info = decode(client.request(world.keys.world_info, encode(WorldInfoRequest()), 5)[0], WorldInfo)
        frame = decode(client.request(world.keys.camera, encode(CameraRequest()), 30)[0], CameraFrame)
    finally:
        client.close()
        world.close()
    assert info.landmark_family == "DICT_5X5_1000" and len(info.landmarks) >= 6
    assert frame.encoding == "jpeg" and (frame.pose_sigma_m, frame.yaw_sigma_deg, frame.k1) == (0.2, 1.5, -0.05)
    truth = world.camera_view()
    assert (frame.north_m, frame.east_m) != (truth.north_m, truth.east_m)
    image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_COLOR)
    published = {lid for lid, _, _ in info.landmarks}
    seen = set(_detect(image))
    assert len(seen) >= 6 and seen <= published
    assert set(_detect(image, "DICT_4X4_1000")) == set(range(4))


def test_a_region_of_the_sensor_renders_the_pixels_that_region_of_the_whole_image_has():
    """Through the realistic lens, lighting and vignetting (noise off: its draw differs), the
    region is rendered alone from the part of the pinhole canvas it samples."""
    from scenarios.maps import resolve_map
    from sim_world.camera import Roi, Scene, camera_model_from, render

    model = camera_model_from("realistic,noise_std=0,width=1280,height=960")
    _, free = resolve_map("warehouse-small", 0)
    scene = Scene(free, {3: (2, 2)}, [(5, 5)])
    pose = (-9.0, 12.0, -8.0, 0.1, 0.01, -0.01)
    whole = render(scene, pose, model, 1.0).astype(int)
    for roi in (Roi(0, 0, 200, 150), Roi(700, 400, 300, 250), Roi(1180, 860, 100, 100)):
        part = render(scene, pose, model, 1.0, roi=roi).astype(int)
        assert part.shape == (roi.height, roi.width, 3)
        assert np.abs(part - whole[roi.y:roi.y + roi.height, roi.x:roi.x + roi.width]).max() <= 1
