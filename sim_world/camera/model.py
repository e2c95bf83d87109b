"""The camera's parameters: intrinsics, lens distortion, image degradations, the pose
estimate's error, and the named presets `--camera` starts from.

Every key, its default (the `ideal` camera: today's perfect pinhole with the true
pose) and its meaning is in KEYS; docs/camera-and-perception.md's table of keys is written from it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from protocol.errors import MissionError, UavRobotsError

MAX_SIDE_PX = 8192   # 67 MP: beyond any drone camera, and a frame still fits the protocol's image limit

# key: (default, what it is). The defaults are the ideal camera.
KEYS: dict[str, tuple[Any, str]] = {
    "width": (1280, "image width, pixels (the world's drone camera: 4000)"),
    "height": (960, "image height, pixels (the world's drone camera: 3000)"),
    "hfov_deg": (90.0, "horizontal field of view of the pinhole, degrees (sets fx when fx is not given)"),
    "fx": (None, "focal length, pixels (default from hfov_deg)"),
    "fy": (None, "focal length, pixels (default fx: square pixels)"),
    "cx": (None, "principal point, pixels (default the image centre, (width - 1) / 2)"),
    "cy": (None, "principal point, pixels (default (height - 1) / 2)"),
    "k1": (0.0, "radial distortion (Brown-Conrady, OpenCV's order k1 k2 p1 p2 k3); negative = barrel"),
    "k2": (0.0, "radial distortion, r^4 term"),
    "p1": (0.0, "tangential distortion"),
    "p2": (0.0, "tangential distortion"),
    "k3": (0.0, "radial distortion, r^6 term"),
    "vignetting": (0.0, "fraction of brightness lost in the image corners (radial, r^2; 0 = none), [0, 1)"),
    "lighting": (0.0, "fraction of brightness lost across the image along lighting_angle_deg, [0, 1)"),
    "lighting_angle_deg": (0.0, "direction of the lighting gradient in the image, degrees"),
    "blur_sigma": (0.0, "Gaussian defocus, pixels"),
    "exposure_ms": (0.0, "exposure time: motion blur along the ground-projected velocity, milliseconds"),
    "noise_std": (0.0, "Gaussian sensor noise, grey levels"),
    "jpeg_quality": (0, "JPEG quality 1..100 of the published image; 0 = lossless PNG"),
    "pose_sigma_m": (0.0, "1-sigma error of the published horizontal position (a drifting bias plus "
                          "white noise; altitude a quarter of it), metres"),
    "yaw_sigma_deg": (0.0, "1-sigma error of the published yaw (drifting bias plus white noise), degrees"),
    "attitude_sigma_deg": (0.0, "1-sigma white error of the published roll and pitch, degrees"),
    "gimbal": (1, "1: the camera is stabilised, level whatever the vehicle's attitude (today's camera); "
                  "0: fixed to the body, it sees the floor through the vehicle's roll and pitch"),
}
INT_KEYS = frozenset({"width", "height", "jpeg_quality", "gimbal"})
# Keys the camera once carried: where they live now (the floor's marks are the scene's, the wobble the vehicle's).
MOVED = {"landmark_spacing": "the scene's: --scene landmark_spacing=N", "goal_pads": "the scene's: --scene goal_pads=0|1",
         "wobble_deg": "the vehicle's: --wobble DEG"}

PRESETS: dict[str, dict[str, float]] = {
    "ideal": {},
    # A calibrated indoor survey drone: a mild barrel lens, EKF pose from optical flow
    # and a rangefinder, a rolling hover, a compressed video-grade stream.
    "realistic": {"k1": -0.05, "k2": 0.01, "p1": 0.0003, "p2": -0.0002, "vignetting": 0.3, "lighting": 0.15,
                  "lighting_angle_deg": 30.0, "exposure_ms": 4.0, "noise_std": 3.0, "jpeg_quality": 90,
                  "pose_sigma_m": 0.2, "yaw_sigma_deg": 1.5, "attitude_sigma_deg": 0.2, "gimbal": 0},
}
# The world's camera when --camera names no preset (`--camera ideal` gives the perfect one).
DEFAULT_CAMERA_PRESET = "realistic"


@dataclass(frozen=True)
class CameraModel:
    """Pinhole intrinsics with Brown-Conrady distortion, image degradations and the error
    of the pose estimate published with each image. Keys and defaults: KEYS."""
    width: int = 1280
    height: int = 960
    hfov_deg: float = 90.0
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    noise_std: float = 0.0
    blur_sigma: float = 0.0
    lighting: float = 0.0
    lighting_angle_deg: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    vignetting: float = 0.0
    exposure_ms: float = 0.0
    jpeg_quality: int = 0
    pose_sigma_m: float = 0.0
    yaw_sigma_deg: float = 0.0
    attitude_sigma_deg: float = 0.0
    gimbal: int = 1

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16:
            raise MissionError(f"camera: image size {self.width}x{self.height} is too small (16x16 at least)")
        if self.width > MAX_SIDE_PX or self.height > MAX_SIDE_PX:
            raise MissionError(f"camera: image size {self.width}x{self.height} is too large "
                               f"({MAX_SIDE_PX} pixels per side at most)")
        for f in fields(self):
            v = getattr(self, f.name)
            if v is not None and not math.isfinite(float(v)):
                raise MissionError(f"camera: {f.name} must be a finite number, got {v}")
        if self.fx is None and not 1.0 <= self.hfov_deg <= 170.0:
            raise MissionError(f"camera: horizontal field of view {self.hfov_deg} deg is not in [1, 170]")
        fx = self.fx if self.fx is not None else (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)
        object.__setattr__(self, "fx", float(fx))
        object.__setattr__(self, "fy", float(self.fy if self.fy is not None else fx))
        object.__setattr__(self, "cx", float(self.cx if self.cx is not None else (self.width - 1) / 2))
        object.__setattr__(self, "cy", float(self.cy if self.cy is not None else (self.height - 1) / 2))
        if not (self.fx > 0 and self.fy > 0):
            raise MissionError(f"camera: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if self.noise_std < 0 or self.blur_sigma < 0 or not 0.0 <= self.lighting < 1.0:
            raise MissionError("camera: noise_std and blur_sigma must be >= 0 and lighting in [0, 1)")
        if not 0.0 <= self.vignetting < 1.0:
            raise MissionError(f"camera: vignetting {self.vignetting} is not in [0, 1)")
        for name in ("exposure_ms", "pose_sigma_m", "yaw_sigma_deg", "attitude_sigma_deg"):
            if getattr(self, name) < 0:
                raise MissionError(f"camera: {name} must be >= 0, got {getattr(self, name)}")
        if self.exposure_ms > 1000 or self.attitude_sigma_deg > 30 or self.yaw_sigma_deg > 180:
            raise MissionError("camera: exposure_ms is at most 1000, attitude_sigma_deg at most 30, "
                               "yaw_sigma_deg at most 180")
        for name, lo, hi in (("jpeg_quality", 0, 100), ("gimbal", 0, 1)):
            v = getattr(self, name)
            if v != int(v) or not lo <= v <= hi:
                raise MissionError(f"camera: {name} {v} is not a whole number in [{lo}, {hi}]")
            object.__setattr__(self, name, int(v))
        if max(abs(self.k1), abs(self.k2), abs(self.k3)) > 1.0 or max(abs(self.p1), abs(self.p2)) > 0.1:
            raise MissionError("camera: distortion beyond a real lens (|k1|, |k2|, |k3| <= 1, |p1|, |p2| <= 0.1)")
        self._check_distortion_monotonic()

    def _check_distortion_monotonic(self) -> None:
        """A lens whose radial mapping folds back inside the image cannot be inverted."""
        if not self.distorted:
            return
        r_max = math.hypot(max(self.cx, self.width - 1 - self.cx) / self.fx,
                           max(self.cy, self.height - 1 - self.cy) / self.fy) * 1.2
        r = np.linspace(0.0, r_max, 400)
        rd = r * (1 + self.k1 * r ** 2 + self.k2 * r ** 4 + self.k3 * r ** 6)
        if np.any(np.diff(rd) <= 0):
            raise MissionError(f"camera: the distortion (k1={self.k1}, k2={self.k2}, k3={self.k3}) folds the "
                               "image over itself within the field of view")

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV's (k1, k2, p1, p2, k3)."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3], dtype=np.float64)

    @property
    def distorted(self) -> bool:
        return any((self.k1, self.k2, self.p1, self.p2, self.k3))


def camera_options(text: str) -> dict[str, Any]:
    """`--camera` text -> CameraModel keys: an optional preset name first, then name=number
    pairs over it. No preset named: DEFAULT_CAMERA_PRESET."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    preset = DEFAULT_CAMERA_PRESET
    if parts and "=" not in parts[0]:
        preset = parts.pop(0)
        if preset not in PRESETS:
            raise UavRobotsError(f"--camera {text!r}: unknown preset {preset!r} (presets: {', '.join(PRESETS)})")
    out: dict[str, Any] = dict(PRESETS[preset])
    for part in parts:
        key, sep, value = part.partition("=")
        key = key.strip()
        if not sep:
            why = "a preset comes first" if key in PRESETS else "not name=number"
            raise UavRobotsError(f"--camera {text!r}: {part!r}: {why}")
        if key in MOVED:
            raise UavRobotsError(f"--camera {text!r}: {key} is not the camera's but {MOVED[key]}")
        if key not in KEYS:
            raise UavRobotsError(f"--camera {text!r}: unknown key {key!r} (keys: {', '.join(KEYS)})")
        try:
            num = float(value)
        except ValueError:
            raise UavRobotsError(f"--camera {text!r}: {part!r} is not name=number") from None
        if not math.isfinite(num):
            raise UavRobotsError(f"--camera {text!r}: {part!r} is not a finite number")
        out[key] = int(num) if key in INT_KEYS and num == int(num) else num
    return out


def camera_preset(text: str) -> str:
    """The preset `--camera` text starts from (DEFAULT_CAMERA_PRESET when it names none)."""
    first = (text or "").split(",", 1)[0].strip()
    return first if first and "=" not in first else DEFAULT_CAMERA_PRESET


def camera_model_from(text: str, base: dict[str, Any] | None = None) -> CameraModel:
    """A CameraModel from `--camera` text over `base` keys (e.g. the drone camera's size)."""
    try:
        return CameraModel(**{**(base or {}), **camera_options(text)})
    except MissionError as exc:
        raise UavRobotsError(f"--camera {text!r}: {exc}") from None
