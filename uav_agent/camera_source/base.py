"""What every camera source shares: its configuration, the `CameraSource` interface, and the
pure parts that turn a calibration, a pose and an image file into a `CameraFrame`."""
from __future__ import annotations

import io
import json
import math
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable
from urllib.parse import urlsplit

from protocol.errors import MissionError, UavRobotsError
from protocol.geo import geo_to_ned
from protocol.messages import CameraFrame
from protocol.codec import encode
from protocol.transport import PendingRequest

KINDS = ("zenoh", "mavlink", "video")
DEFAULT_CAMERA_MAVLINK = "udpin:127.0.0.1:14560"
CAMERA_TIMEOUT_S = 30.0     # an image rendered and sent (the world's camera query has the same)
QUERY_TIMEOUT_S = 10.0
ACK_TIMEOUT_S = 1.0         # a command is sent again after this, three times in all (MAVLink's habit)
FETCH_TIMEOUT_S = 10.0
VIDEO_FRAME_TIMEOUT_S = 5.0
SOURCE_SYSTEM, SOURCE_COMPONENT = 1, 191   # the UAV agent: the drone's onboard computer
CAMERA_COMPONENT = 100                    # MAV_COMP_ID_CAMERA
OUR_VENDOR = "uav-robots"                 # a camera that states each image's index in the capture's ACK
Pose = tuple[float, float, float, float, float, float]   # north, east, down, yaw, roll, pitch


@dataclass(frozen=True)
class CameraSourceConfig:
    kind: str = "zenoh"
    mavlink: str = DEFAULT_CAMERA_MAVLINK   # the camera component's link (mavlink, and video without a URL)
    video: str | None = None                # udp://HOST:PORT (RTP H.264) or an SDP file or http URL
    calibration: str | None = None          # a calibration JSON file or http URL

    def check(self) -> None:
        """One line for bad input, before anything starts."""
        if self.kind not in KINDS:
            raise UavRobotsError(f"--camera-source {self.kind!r}: one of {', '.join(KINDS)}")
        if self.kind == "video":
            require_pyav()
        if self.video is not None:
            url = urlsplit(self.video)
            if url.scheme == "udp" and not (url.hostname and port(url)):
                raise UavRobotsError(f"--camera-video {self.video!r}: give udp://HOST:PORT, an .sdp file or its URL")
            if url.scheme not in ("udp", "http", "https") and not Path(self.video).is_file():
                raise UavRobotsError(f"--camera-video {self.video!r}: no such SDP file")
        if self.calibration is not None and not self.calibration.startswith(("http://", "https://")):
            read_calibration(self.calibration)


def port(url: Any) -> int | None:
    try:
        return url.port
    except ValueError:
        return None




def require_pyav() -> Any:
    try:
        import av
    except ImportError:
        raise UavRobotsError("a video camera source needs PyAV: pip install 'uav-robots[video]'") from None
    return av


def as_text(value: Any) -> str:
    return value if isinstance(value, str) else bytes(value).rstrip(b"\0").decode("utf-8", "replace")


def file_beside(uri: str, name: str) -> str | None:
    """The http URL of `name` in the folder of `uri` (the camera's definition file)."""
    if not uri.startswith(("http://", "https://")):
        return None
    return uri.rsplit("/", 1)[0] + "/" + name


# ------------------------------------------------------------------ pure parts
def read_calibration(where: str) -> dict[str, Any]:
    """A calibration JSON (`calibration.json`'s keys: width, height, fx, fy, cx, cy, k1..k3,
    pose_sigma_m, yaw_sigma_deg) from a file or an http URL."""
    try:
        if where.startswith(("http://", "https://")):
            with urllib.request.urlopen(where, timeout=FETCH_TIMEOUT_S) as r:
                data = json.loads(r.read(1 << 20))
        else:
            data = json.loads(Path(where).read_text())
        cal = {k: float(data[k]) for k in ("width", "height", "fx", "fy", "cx", "cy")}
        for k in ("k1", "k2", "p1", "p2", "k3", "pose_sigma_m", "yaw_sigma_deg"):
            cal[k] = float(data.get(k, 0.0))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UavRobotsError(f"camera calibration {where!r}: {type(exc).__name__}: {exc}") from None
    if not all(math.isfinite(v) for v in cal.values()) or min(cal["width"], cal["height"], cal["fx"], cal["fy"]) <= 0:
        raise UavRobotsError(f"camera calibration {where!r}: sizes and focal lengths must be positive numbers")
    return cal


def pinhole(width: int, height: int, focal_mm: float, sensor_w_mm: float, sensor_h_mm: float) -> dict[str, Any]:
    """The calibration CAMERA_INFORMATION states: a pinhole with its principal point centred."""
    return {"width": width, "height": height, "fx": focal_mm / sensor_w_mm * width,
            "fy": focal_mm / sensor_h_mm * height, "cx": (width - 1) / 2, "cy": (height - 1) / 2}


def _conjugate(q: tuple[float, ...]) -> tuple[float, float, float, float]:
    return q[0], -q[1], -q[2], -q[3]


def _multiply(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


_S = math.sqrt(0.5)
NADIR_MOUNT = (_S, 0.0, -_S, 0.0)   # pitch -90 deg: the camera looks down the body's z axis


def body_attitude(q: tuple[float, ...]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of the body carrying a nadir camera whose orientation is `q` (w, x, y,
    z; the gimbal convention: zero rotation looks north along the camera's x axis)."""
    n = math.sqrt(sum(v * v for v in q))
    if not (math.isfinite(n) and n > 0.5):
        raise MissionError(f"the camera's attitude quaternion {list(q)} is not a rotation")
    w, x, y, z = _multiply(tuple(v / n for v in q), _conjugate(NADIR_MOUNT))
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def frame_from(cal: dict[str, Any], pose: Pose, time_s: float, image: bytes = b"", encoding: str = "png",
               size: tuple[int, int] | None = None) -> CameraFrame:
    """The CameraFrame of an image (`size` its pixels, if it is not the calibration's: the
    intrinsics scale with it) taken at `pose`."""
    w, h = size or (int(cal["width"]), int(cal["height"]))
    sx, sy = w / cal["width"], h / cal["height"]
    north, east, down, yaw, roll, pitch = pose
    return CameraFrame(width=w, height=h, fx=cal["fx"] * sx, fy=cal["fy"] * sy, cx=(cal["cx"] + 0.5) * sx - 0.5,
                       cy=(cal["cy"] + 0.5) * sy - 0.5, north_m=north, east_m=east, down_m=down, yaw_rad=yaw,
                       time_s=time_s, png=image, k1=cal.get("k1", 0.0), k2=cal.get("k2", 0.0),
                       p1=cal.get("p1", 0.0), p2=cal.get("p2", 0.0), k3=cal.get("k3", 0.0), roll_rad=roll,
                       pitch_rad=pitch, pose_sigma_m=cal.get("pose_sigma_m", 0.0),
                       yaw_sigma_deg=cal.get("yaw_sigma_deg", 0.0), encoding=encoding)


def captured_pose(msg: Any, home: tuple[float, float, float]) -> Pose:
    """The pose at exposure CAMERA_IMAGE_CAPTURED states, in the floor's NED frame (origin `home`)."""
    north, east = geo_to_ned(msg.lat / 1e7, msg.lon / 1e7, home[0], home[1])
    roll, pitch, yaw = body_attitude(tuple(msg.q))
    return north, east, home[2] - msg.alt / 1000.0, yaw, roll, pitch


def image_size(data: bytes) -> tuple[tuple[int, int], str]:
    """((width, height), "jpeg" or "png") of an image file, from its header."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as img:
            kind = (img.format or "").lower()
            size = img.size
    except (UnidentifiedImageError, OSError) as exc:
        raise MissionError(f"the camera's image file is not an image: {exc}") from None
    if kind not in ("jpeg", "png"):
        raise MissionError(f"the camera's image file is {kind or 'of no known format'}, not JPEG or PNG")
    return size, kind

class Answered(PendingRequest):
    """A request already answered (or one whose answer `fetch` makes when waited for)."""

    def __init__(self, fetch: Callable[[], CameraFrame]) -> None:
        self._fetch = fetch

    def wait(self) -> list[bytes]:
        return [encode(self._fetch())]


class CameraSource:
    """`frame()` one image (or, `calibration_only`, the intrinsics and lens alone); `start(roi)`
    asks for one without waiting for it, the shutter open once `start` and `fence` returned."""
    name = "camera"

    def frame(self, calibration_only: bool = False) -> CameraFrame:
        raise NotImplementedError

    def start(self, roi: Any = None) -> PendingRequest:
        raise NotImplementedError

    def fence(self) -> None:
        """Returns once every image asked for so far has had its shutter opened."""

    def close(self) -> None:
        pass
