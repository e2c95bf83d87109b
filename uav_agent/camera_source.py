"""Where the UAV's images come from: the camera source it is given (`--camera-source`).

Perception never knows which: every source hands over a `CameraFrame` (the image, the
intrinsics and lens, the pose estimate at exposure), as `world/camera` answers it.

- `zenoh` (default): the world's `world/camera` query (docs/protocol.md). The shutter opens
  as the query arrives; `fence` (a `world/info` query on the same session) returns once it has.
- `mavlink`: the MAVLink camera protocol, as a real drone's camera speaks it: the camera
  component's HEARTBEAT, CAMERA_INFORMATION, then MAV_CMD_IMAGE_START_CAPTURE per image; its
  COMMAND_ACK says the shutter opened; CAMERA_IMAGE_CAPTURED gives the pose at exposure
  (lat/lon/alt, mapped to the floor's frame by the site's origin in `WorldInfo`; the camera's
  quaternion) and the file's URL, fetched over HTTP. The lens and the estimate's sigmas come
  from a calibration (`--camera-calibration`, else the `calibration.json` beside the camera's
  definition file, else the pinhole CAMERA_INFORMATION states).
- `video`: the newest frame of an H.264 RTP stream (the stream the camera component announces
  in VIDEO_STREAM_INFORMATION, or `--camera-video`), with the pose from the autopilot's
  telemetry when the frame arrived; the second frame to arrive after the request is taken, so
  it was rendered after it. Regions of interest are not asked of MAVLink or video cameras: they
  send whole images, which perception understands.
"""
from __future__ import annotations

import io
import json
import math
import os
import queue
import tempfile
import threading
import time
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable
from urllib.parse import urlsplit

from protocol.codec import decode, encode
from protocol.errors import MissionError, ProtocolError, UavRobotsError
from protocol.geo import geo_to_ned
from protocol.keys import Keys
from protocol.messages import CameraFrame, CameraRequest, WorldInfo, WorldInfoRequest
from protocol.transport import PendingRequest, Transport

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
            if url.scheme == "udp" and not (url.hostname and _port(url)):
                raise UavRobotsError(f"--camera-video {self.video!r}: give udp://HOST:PORT, an .sdp file or its URL")
            if url.scheme not in ("udp", "http", "https") and not Path(self.video).is_file():
                raise UavRobotsError(f"--camera-video {self.video!r}: no such SDP file")
        if self.calibration is not None and not self.calibration.startswith(("http://", "https://")):
            read_calibration(self.calibration)


def _port(url: Any) -> int | None:
    try:
        return url.port
    except ValueError:
        return None


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


class _Done(PendingRequest):
    """A request already answered (or one whose answer `fetch` makes when waited for)."""

    def __init__(self, fetch: Callable[[], CameraFrame]) -> None:
        self._fetch = fetch

    def wait(self) -> list[bytes]:
        return [encode(self._fetch())]


# ------------------------------------------------------------------ sources
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


class ZenohSource(CameraSource):
    """The world's `world/camera` query."""
    name = "the world's camera"

    def __init__(self, transport: Transport, keys: Keys, next_seq: Callable[[], int]) -> None:
        self.transport, self.keys, self._next = transport, keys, next_seq

    def frame(self, calibration_only: bool = False) -> CameraFrame:
        replies = self.transport.request(self.keys.camera, encode(CameraRequest(calibration_only=calibration_only,
                                                                                seq=self._next())), CAMERA_TIMEOUT_S)
        if not replies:
            raise MissionError(f"no answer from the world's camera within {CAMERA_TIMEOUT_S:g} s")
        try:
            return decode(replies[0], CameraFrame)
        except ProtocolError as exc:
            raise MissionError(f"the world's camera answered garbage: {exc}") from None

    def start(self, roi: Any = None) -> PendingRequest:
        area = {} if roi is None else {"roi_x": roi.x, "roi_y": roi.y, "roi_width": roi.width,
                                       "roi_height": roi.height}
        return self.transport.request_start(self.keys.camera, encode(CameraRequest(seq=self._next(), **area)),
                                            CAMERA_TIMEOUT_S)

    def fence(self) -> None:
        self.transport.request(self.keys.world_info, encode(WorldInfoRequest(seq=self._next())), QUERY_TIMEOUT_S)


class CameraLink:
    """The camera component over MAVLink: its heartbeat, its information, commands and their ACKs,
    CAMERA_IMAGE_CAPTURED by index."""

    def __init__(self, url: str, timeout_s: float) -> None:
        from pymavlink import mavutil

        self.url = url
        try:
            self.conn = mavutil.mavlink_connection(url, source_system=SOURCE_SYSTEM, source_component=SOURCE_COMPONENT)
        except Exception as exc:  # pymavlink raises anything from ValueError to OSError here
            raise MissionError(f"cannot open the camera's MAVLink link {url!r}: {exc}") from None
        self._cv = threading.Condition()
        self._stop = threading.Event()
        self.camera: tuple[int, int] | None = None     # (system, component)
        self._latest: dict[str, Any] = {}              # message type -> the newest one
        self._acks: queue.Queue[Any] = queue.Queue()
        self.captured: dict[int, Any] = {}             # image index -> CAMERA_IMAGE_CAPTURED
        self._order: list[int] = []                    # indexes in the order they arrived
        self._send_lock = threading.Lock()
        self._thread = threading.Thread(target=self._receive, name="camera-link", daemon=True)
        self._thread.start()
        try:
            self._wait(lambda: self.camera is not None, timeout_s,
                       f"no MAVLink camera (a HEARTBEAT of MAV_TYPE_CAMERA) at {url} within {timeout_s:g} s")
            self.information = self.request(259, "CAMERA_INFORMATION")
        except MissionError:
            self.close()
            raise

    def _receive(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_match(blocking=True, timeout=0.2)
            except Exception:  # noqa: BLE001 - a closed socket or a garbled frame
                if self._stop.is_set():
                    return
                continue
            if msg is None:
                continue
            kind = msg.get_type()
            with self._cv:
                if kind == "HEARTBEAT" and msg.type == 30 and self.camera is None:   # MAV_TYPE_CAMERA
                    self.camera = (msg.get_srcSystem(), msg.get_srcComponent())
                if self.camera is None or (msg.get_srcSystem(), msg.get_srcComponent()) != self.camera:
                    continue
                if kind == "COMMAND_ACK":
                    self._acks.put(msg)
                elif kind == "CAMERA_IMAGE_CAPTURED":
                    if msg.image_index not in self.captured:
                        self._order.append(msg.image_index)
                    self.captured[msg.image_index] = msg
                self._latest[kind] = msg
                self._cv.notify_all()

    def _wait(self, done: Callable[[], bool], timeout_s: float, why: str) -> None:
        with self._cv:
            if not self._cv.wait_for(done, timeout=timeout_s):
                raise MissionError(why)

    def send(self, msg: Any) -> None:
        with self._send_lock:
            self.conn.mav.send(msg)

    def command(self, command: int, *params: float) -> Any:
        """COMMAND_LONG to the camera, sent up to three times; its COMMAND_ACK."""
        from pymavlink.dialects.v20 import common as mavlink

        p = list(params) + [0.0] * (7 - len(params))
        system, component = self.camera or (SOURCE_SYSTEM, CAMERA_COMPONENT)
        for attempt in range(3):
            self.send(mavlink.MAVLink_command_long_message(system, component, command, attempt, *p))
            deadline = time.monotonic() + ACK_TIMEOUT_S
            while (left := deadline - time.monotonic()) > 0:
                try:
                    ack = self._acks.get(timeout=left)
                except queue.Empty:
                    break
                if ack.command == command:
                    return ack
        raise MissionError(f"the camera at {self.url} did not acknowledge command {command} within "
                           f"{3 * ACK_TIMEOUT_S:g} s")

    def request(self, msg_id: int, kind: str, param2: float = 0.0) -> Any:
        """MAV_CMD_REQUEST_MESSAGE and the message it brings."""
        with self._cv:
            before = self._latest.get(kind)
        ack = self.command(512, msg_id, param2)
        if ack.result != 0:
            raise MissionError(f"the camera at {self.url} refused to send {kind} (MAV_RESULT {ack.result})")
        self._wait(lambda: self._latest.get(kind) is not before, QUERY_TIMEOUT_S,
                   f"the camera at {self.url} acknowledged but sent no {kind} within {QUERY_TIMEOUT_S:g} s")
        return self._latest[kind]

    def image(self, index: int | None, after: int, timeout_s: float) -> Any:
        """CAMERA_IMAGE_CAPTURED of image `index`, or (None) the first to arrive after the
        `after`-th one that nobody claimed yet."""
        def found() -> Any:
            if index is not None:
                return self.captured.get(index)
            return next((self.captured[i] for i in self._order[after:]), None)
        self._wait(lambda: found() is not None, timeout_s,
                   f"the camera at {self.url} sent no CAMERA_IMAGE_CAPTURED within {timeout_s:g} s")
        with self._cv:
            return found()

    def arrived(self) -> int:
        with self._cv:
            return len(self._order)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        try:
            self.conn.close()
        except OSError:
            pass


def _beside(uri: str, name: str) -> str | None:
    """The http URL of `name` in the folder of `uri` (the camera's definition file)."""
    if not uri.startswith(("http://", "https://")):
        return None
    return uri.rsplit("/", 1)[0] + "/" + name


class MavlinkSource(CameraSource):
    """The MAVLink camera protocol: a capture command per image, the file fetched over HTTP."""
    name = "the MAVLink camera"

    def __init__(self, cfg: CameraSourceConfig, home: tuple[float, float, float], timeout_s: float) -> None:
        self.home = home
        self.link = CameraLink(cfg.mavlink, timeout_s)
        info = self.link.information
        self._indexed = _text(info.vendor_name) == OUR_VENDOR
        try:
            self.calibration = self._calibration(cfg.calibration, info)
        except (MissionError, UavRobotsError):
            self.link.close()
            raise
        self._sequence = 0
        self._claimed = 0
        self._lock = threading.Lock()

    def _calibration(self, given: str | None, info: Any) -> dict[str, Any]:
        beside = _beside(_text(info.cam_definition_uri), "calibration.json")
        if given:
            return read_calibration(given)
        if beside:
            try:
                return read_calibration(beside)
            except UavRobotsError:
                pass   # a real camera has no such file: its stated pinhole, without distortion
        if not (info.focal_length > 0 and info.sensor_size_h > 0 and info.sensor_size_v > 0
                and info.resolution_h and info.resolution_v):
            raise MissionError(f"the camera at {self.link.url} states no focal length, sensor size and resolution, "
                               "and no calibration was given (--camera-calibration)")
        return pinhole(info.resolution_h, info.resolution_v, info.focal_length, info.sensor_size_h, info.sensor_size_v)

    def frame(self, calibration_only: bool = False) -> CameraFrame:
        if calibration_only:
            return frame_from(self.calibration, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 0.0)
        return decode(self.start().wait()[0], CameraFrame)

    def start(self, roi: Any = None) -> PendingRequest:
        with self._lock:
            self._sequence += 1
            after = self.link.arrived()
            ack = self.link.command(2000, 0, 0, 1, self._sequence)   # MAV_CMD_IMAGE_START_CAPTURE, one image
        if ack.result != 0:
            raise MissionError(f"the camera at {self.link.url} refused a capture (MAV_RESULT {ack.result})")
        index = ack.result_param2 if self._indexed else None
        return _Done(lambda: self._fetch(index, after))

    def _fetch(self, index: int | None, after: int) -> CameraFrame:
        msg = self.link.image(index, after, CAMERA_TIMEOUT_S)
        if msg.capture_result != 1:
            raise MissionError(f"the camera at {self.link.url} failed image {msg.image_index}")
        url = _text(msg.file_url)
        if not url.startswith(("http://", "https://")):
            raise MissionError(f"the camera's image {msg.image_index} has no http URL ({url!r})")
        try:
            with urllib.request.urlopen(url, timeout=FETCH_TIMEOUT_S) as r:
                data = r.read()
        except OSError as exc:
            raise MissionError(f"cannot fetch the camera's image {url}: {exc}") from None
        size, kind = image_size(data)
        return frame_from(self.calibration, captured_pose(msg, self.home), msg.time_boot_ms / 1000.0, data, kind, size)

    def close(self) -> None:
        self.link.close()


class VideoSource(CameraSource):
    """Frames of an H.264 RTP stream, each with the autopilot's pose when it arrived."""
    name = "the video stream"

    def __init__(self, cfg: CameraSourceConfig, pose: Callable[[], Pose], timeout_s: float) -> None:
        self.av = require_pyav()
        self._pose = pose
        self.link: CameraLink | None = None
        stream, cal = cfg.video, read_calibration(cfg.calibration) if cfg.calibration else None
        if stream is None or cal is None:   # what the camera component announces, as a ground station finds it
            self.link = CameraLink(cfg.mavlink, timeout_s)
            try:
                info = self.link.request(269, "VIDEO_STREAM_INFORMATION", 1)
                stream = stream or _text(info.uri)
                cal = cal or self._announced(info)
            except (MissionError, UavRobotsError):
                self.link.close()
                raise
        self.stream, self.calibration = stream, cal
        self._sdp, self._temporary = sdp_file(stream)
        self._cv = threading.Condition()
        self._latest: tuple[Any, Pose | None] | None = None
        self._count = 0
        self._error = ""
        self._stop = threading.Event()
        self._t0 = time.monotonic()
        self._thread = threading.Thread(target=self._decode, name="camera-video", daemon=True)
        self._thread.start()

    def _announced(self, info: Any) -> dict[str, Any]:
        """The stream's calibration beside the camera's definition file, else its stated field of view."""
        uri = _text(self.link.information.cam_definition_uri) if self.link else ""
        beside = _beside(uri, "video/calibration.json")
        if beside:
            try:
                return read_calibration(beside)
            except UavRobotsError:
                pass
        if not (0 < info.hfov < 180 and info.resolution_h and info.resolution_v):
            raise MissionError("the camera's video stream states no field of view: give --camera-calibration")
        f = info.resolution_h / 2 / math.tan(math.radians(info.hfov) / 2)
        return {"width": info.resolution_h, "height": info.resolution_v, "fx": f, "fy": f,
                "cx": (info.resolution_h - 1) / 2, "cy": (info.resolution_v - 1) / 2}

    def _decode(self) -> None:
        av = self.av
        try:
            container = av.open(self._sdp, format="sdp", timeout=(CAMERA_TIMEOUT_S, CAMERA_TIMEOUT_S),
                                options={"protocol_whitelist": "file,udp,rtp", "fflags": "nobuffer",
                                         "analyzeduration": "1000000", "probesize": "100000",
                                         "reorder_queue_size": "0"})
        except Exception as exc:  # noqa: BLE001 - FFmpeg's errors, said when an image is asked for
            with self._cv:
                self._error = f"cannot open the video stream {self.stream}: {exc}"
                self._cv.notify_all()
            return
        try:
            for frame in container.decode(video=0):
                if self._stop.is_set():
                    break
                try:
                    pose: Pose | None = self._pose()
                except MissionError:   # no autopilot yet: the pose is read when the image is asked for
                    pose = None
                with self._cv:
                    self._latest = (frame, pose)
                    self._count += 1
                    self._cv.notify_all()
        except Exception as exc:  # noqa: BLE001 - the stream ended or broke
            with self._cv:
                self._error = f"the video stream {self.stream} stopped: {exc}"
                self._cv.notify_all()
        finally:
            container.close()

    def frame(self, calibration_only: bool = False) -> CameraFrame:
        if calibration_only:
            return frame_from(self.calibration, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 0.0)
        return decode(self.start().wait()[0], CameraFrame)

    def start(self, roi: Any = None) -> PendingRequest:
        """The second frame to arrive from now: the first may have been rendered before the request."""
        with self._cv:
            first = self._count
            if not self._cv.wait_for(lambda: self._count >= first + 2 or self._error, VIDEO_FRAME_TIMEOUT_S) \
                    or self._latest is None or self._count < first + 2:
                raise MissionError(self._error or f"no frame of the video stream {self.stream} within "
                                                  f"{VIDEO_FRAME_TIMEOUT_S:g} s")
            picture, pose = self._latest
        import cv2

        image = picture.to_ndarray(format="bgr24")
        ok, png = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        if not ok:  # pragma: no cover - OpenCV refuses only malformed arrays
            raise MissionError("a video frame could not be encoded")
        frame = frame_from(self.calibration, pose or self._pose(), time.monotonic() - self._t0, png.tobytes(), "png",
                           (image.shape[1], image.shape[0]))
        return _Done(lambda: frame)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        if self.link is not None:
            self.link.close()
        if self._temporary:
            try:
                os.unlink(self._sdp)
            except OSError:
                pass


def _text(value: Any) -> str:
    return value if isinstance(value, str) else bytes(value).rstrip(b"\0").decode("utf-8", "replace")


def sdp_file(stream: str) -> tuple[str, bool]:
    """(an SDP file describing `stream`, whether it is ours to delete). `udp://HOST:PORT` is taken
    as QGroundControl takes it: RTP, H.264, payload type 96."""
    url = urlsplit(stream)
    if url.scheme == "udp":
        text = (f"v=0\r\no=- 0 0 IN IP4 {url.hostname}\r\ns=camera\r\nc=IN IP4 {url.hostname}\r\nt=0 0\r\n"
                f"m=video {_port(url)} RTP/AVP 96\r\na=rtpmap:96 H264/90000\r\na=fmtp:96 packetization-mode=1\r\n")
    elif url.scheme in ("http", "https"):
        try:
            with urllib.request.urlopen(stream, timeout=FETCH_TIMEOUT_S) as r:
                text = r.read(1 << 16).decode("utf-8", "replace")
        except OSError as exc:
            raise MissionError(f"cannot fetch the video stream's SDP {stream}: {exc}") from None
    else:
        return stream, False
    fd, path = tempfile.mkstemp(prefix="uav-camera-", suffix=".sdp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    return path, True


def require_pyav() -> Any:
    try:
        import av
    except ImportError:
        raise UavRobotsError("a video camera source needs PyAV: pip install 'uav-robots[video]'") from None
    return av


def open_camera_source(cfg: CameraSourceConfig, transport: Transport, keys: Keys, info: WorldInfo,
                       next_seq: Callable[[], int], pose: Callable[[], Pose],
                       timeout_s: float = 30.0) -> CameraSource:
    """The source `cfg` names; the floor's origin is the site's (`info`), as the UAV's frame is."""
    cfg.check()
    if cfg.kind == "mavlink":
        return MavlinkSource(cfg, (info.home_lat, info.home_lon, info.home_alt_m), timeout_s)
    if cfg.kind == "video":
        return VideoSource(cfg, pose, timeout_s)
    return ZenohSource(transport, keys, next_seq)
