"""The world's camera as a MAVLink camera component (Camera Protocol v2), on a link of its own.

What a ground station (QGroundControl, MAVProxy, MAVSDK's camera plugin, a pymavlink script)
finds on a real drone's camera: a HEARTBEAT of MAV_TYPE_CAMERA from MAV_COMP_ID_CAMERA (the
autopilot's system id); CAMERA_INFORMATION (focal length, sensor size and resolution: the
pinhole a survey planner reads; a definition file URI), CAMERA_SETTINGS, STORAGE_INFORMATION,
CAMERA_CAPTURE_STATUS and, with video, VIDEO_STREAM_INFORMATION / VIDEO_STREAM_STATUS, each on
MAV_CMD_REQUEST_MESSAGE (or the older MAV_CMD_REQUEST_CAMERA_INFORMATION & co.).

MAV_CMD_IMAGE_START_CAPTURE opens the shutter as it arrives (one image, or a series every
`interval` s until MAV_CMD_IMAGE_STOP_CAPTURE), answers COMMAND_ACK ACCEPTED once it has (its
`result_param2` is the image's index), renders the image on the world's camera thread, and
sends CAMERA_IMAGE_CAPTURED: the exposure's time (`time_boot_ms` is the world's simulated clock,
CameraFrame's `time_s`), the pose ESTIMATE at exposure (lat/lon/alt AMSL and alt relative to
the floor's origin, the camera's attitude quaternion), the index, the result and the file's
http:// URL, served by `served.FileServer` as real cameras serve theirs.

The quaternion is the camera's orientation in NED, w x y z, zero rotation looking north along
its x axis (a gimbal's convention): our nadir camera is the body's attitude turned pitch -90 deg
(`camera_quaternion`). The lens's distortion and the pose estimate's stated sigmas have no
field in the protocol: they are in `calibration.json` beside the definition file.
"""
from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import MissionError
from protocol.geo import ned_to_geo

from .model import CameraModel
from .served import CameraFiles, FileServer

COMPONENT_ID = mavlink.MAV_COMP_ID_CAMERA
PIXEL_PITCH_MM = 0.00155   # a 1/2.3" 12 MP sensor's pixel: 4000 px make 6.2 mm
HEARTBEAT_S = 1.0
MAX_PENDING = 8            # images accepted and not yet rendered; more are refused TEMPORARILY_REJECTED
KEEP_CAPTURED = 1000       # CAMERA_IMAGE_CAPTURED messages kept to be sent again on request
MIN_INTERVAL_S = 0.1
VENDOR, MODEL = b"uav-robots", b"simulated nadir camera"
DEFINITION_PATH, CALIBRATION_PATH = "/camera.xml", "/calibration.json"

_REQUESTS = {   # the older MAV_CMD_REQUEST_* commands -> the message each asks for
    mavlink.MAV_CMD_REQUEST_CAMERA_INFORMATION: mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION,
    mavlink.MAV_CMD_REQUEST_CAMERA_SETTINGS: mavlink.MAVLINK_MSG_ID_CAMERA_SETTINGS,
    mavlink.MAV_CMD_REQUEST_STORAGE_INFORMATION: mavlink.MAVLINK_MSG_ID_STORAGE_INFORMATION,
    mavlink.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS: mavlink.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
    mavlink.MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION: mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION,
    mavlink.MAV_CMD_REQUEST_VIDEO_STREAM_STATUS: mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS,
}

DEFINITION_XML = b"""<?xml version="1.0" encoding="UTF-8" ?>
<mavlinkcamera>
    <definition version="1">
        <model>simulated nadir camera</model>
        <vendor>uav-robots</vendor>
    </definition>
    <parameters>
    </parameters>
</mavlinkcamera>
"""


# ------------------------------------------------------------------ pure parts
def quaternion_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of the aerospace ZYX rotation: body FRD -> NED."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def quaternion_multiply(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


NADIR_MOUNT = quaternion_from_euler(0.0, -math.pi / 2, 0.0)   # the camera looks down the body's z axis


def camera_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """The nadir camera's orientation (gimbal convention) for the body's attitude."""
    return quaternion_multiply(quaternion_from_euler(roll, pitch, yaw), NADIR_MOUNT)


def sensor_mm(model: CameraModel) -> tuple[float, float, float]:
    """(focal length, sensor width, sensor height) in mm giving the model's fx and fy over its
    resolution: what CAMERA_INFORMATION can say of a pinhole (fx = f / width_mm * width_px)."""
    focal = model.fx * PIXEL_PITCH_MM
    return focal, model.width * PIXEL_PITCH_MM, model.height * focal / model.fy


def calibration(model: CameraModel) -> dict[str, Any]:
    """What the protocol has no field for: the whole intrinsics (OpenCV's convention), the lens's
    Brown-Conrady distortion, and the pose estimate's stated 1-sigma errors."""
    return {"width": model.width, "height": model.height, "fx": model.fx, "fy": model.fy, "cx": model.cx,
            "cy": model.cy, "k1": model.k1, "k2": model.k2, "p1": model.p1, "p2": model.p2, "k3": model.k3,
            "pose_sigma_m": model.pose_sigma_m, "yaw_sigma_deg": model.yaw_sigma_deg,
            "mount": "nadir: image up is the body's forward, image right its right"}


def _text(value: bytes, size: int) -> list[int]:
    return list(value[:size].ljust(size, b"\0"))


@dataclass(frozen=True)
class CameraLink:
    """How the camera component is reached: its MAVLink link (None: no MAVLink, files only)."""
    url: str | None
    home: tuple[float, float, float]   # the floor's origin: lat, lon (deg), alt AMSL (m)
    system_id: int = 1                 # the autopilot's: a camera is a component of the vehicle
    bind_host: str = "127.0.0.1"       # its MAVLink socket and its HTTP server


# ------------------------------------------------------------------ the component
class MavlinkCamera:
    """`expose()` opens the shutter now and returns what `develop(shot)` renders into a
    CameraFrame; `run(job)` runs a job on the camera's thread (the world's, so that images from
    Zenoh and MAVLink take turns); `video` is a stream.VideoStream or None."""

    def __init__(self, link: CameraLink, model: CameraModel, expose: Callable[[], Any],
                 develop: Callable[[Any], Any], run: Callable[[Callable[[], None]], object],
                 video: Any = None) -> None:
        self.link, self.model, self.video = link, model, video
        self._expose, self._develop, self._run = expose, develop, run
        self.files = CameraFiles()
        self.files.put_doc(DEFINITION_PATH, DEFINITION_XML, "xml")
        self.files.put_doc(CALIBRATION_PATH, json.dumps(calibration(model)).encode(), "json")
        self.server: FileServer | None = None
        self._conn: Any = None
        self._send_lock = threading.Lock()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._t0 = time.monotonic()
        self._index = 0                     # the next image's index
        self._pending = 0
        self._captured: dict[int, Any] = {}   # index -> its CAMERA_IMAGE_CAPTURED, the newest KEEP_CAPTURED
        self._last_sequence = 0             # IMAGE_START_CAPTURE's sequence number: a resend takes no image
        self._series: threading.Thread | None = None
        self._series_stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.refused = 0                    # captures refused: too many waiting to be rendered

    # -------------------------------------------------------------- lifecycle
    def start(self) -> None:
        self.server = FileServer(self.files, self.link.bind_host)
        if self.video is not None:
            self.video.publish(self.files, self.server)
        if self.link.url:
            try:
                self._conn = mavutil.mavlink_connection(self.link.url, source_system=self.link.system_id,
                                                        source_component=COMPONENT_ID)
                if isinstance(self._conn, mavutil.mavudp) and not self._conn.udp_server:
                    self._conn.port.bind((self.link.bind_host, 0))   # never 0.0.0.0 by a first send
            except Exception as exc:  # pymavlink raises anything from ValueError to OSError here
                self.close()
                raise MissionError(f"camera: cannot open its MAVLink link {self.link.url!r}: {exc}") from None
            self._threads.append(threading.Thread(target=self._receive, name="camera-mavlink", daemon=True))
        if self.video is not None:
            self.video.start()
        for t in self._threads:
            t.start()

    def close(self) -> None:
        self._stop.set()
        self._series_stop.set()
        for t in self._threads:
            t.join(2.0)
        if self.video is not None:
            self.video.close()
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:
                pass
            self._conn = None
        if self.server is not None:
            self.server.close()
            self.server = None

    def describe(self) -> str:
        where = self.server.url("") if self.server else "off"
        return (f"camera component {self.link.url or 'without MAVLink'}, files {where}"
                + (f", video {self.video.describe()}" if self.video is not None else ""))

    @property
    def images(self) -> int:
        with self._lock:
            return self._index

    def record(self) -> dict[str, Any]:
        """What the component did, for the world's record."""
        with self._lock:
            out: dict[str, Any] = {"mavlink": self.link.url, "images": self._index, "refused": self.refused,
                                   "failed": sum(1 for m in self._captured.values() if m.capture_result != 1)}
        if self.video is not None:
            out["video"] = {"uri": self.video.cfg.uri, "frames": self.video.frames, "error": self.video.error}
        return out

    # -------------------------------------------------------------- MAVLink
    def _send(self, msg: Any) -> None:
        with self._send_lock:
            conn = self._conn
            if conn is not None:
                try:
                    conn.mav.send(msg)
                except OSError:   # a udpout peer not up yet, or the link closing
                    pass

    def _boot_ms(self) -> int:
        return int((time.monotonic() - self._t0) * 1000) & 0xFFFFFFFF

    def _receive(self) -> None:
        beat = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= beat:
                beat = now + HEARTBEAT_S
                self._send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_CAMERA, mavlink.MAV_AUTOPILOT_INVALID,
                                                             0, 0, mavlink.MAV_STATE_ACTIVE, 3))
            try:
                msg = self._conn.recv_match(blocking=True, timeout=0.2)
            except Exception:  # noqa: BLE001 - a closed socket or a garbled frame: keep serving
                if self._stop.is_set():
                    return
                continue
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            try:
                self._handle(msg)
            except Exception as exc:  # noqa: BLE001 - a well-formed frame with absurd content must not stop the camera
                print(f"warning: camera: cannot handle {msg.get_type()}: {type(exc).__name__}: {exc}", flush=True)

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind not in ("COMMAND_LONG", "COMMAND_INT"):
            return
        if msg.target_system not in (0, self.link.system_id) or msg.target_component not in (0, COMPONENT_ID):
            return
        params = (msg.param1, msg.param2, msg.param3, msg.param4)
        result, then, extra = self._command(msg.command, params)
        if result is None:   # not for a camera (a broadcast command the autopilot answers)
            return
        self._send(mavlink.MAVLink_command_ack_message(msg.command, result, 0, extra, msg.get_srcSystem(),
                                                       msg.get_srcComponent()))
        for m in then:
            self._send(m)

    def _command(self, command: int, p: tuple[float, ...]) -> tuple[int | None, list[Any], int]:
        """(the ACK's result, the messages to send after it, the ACK's result_param2)."""
        ok, no = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_UNSUPPORTED
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE or command in _REQUESTS:
            msg_id = int(p[0]) if command == mavlink.MAV_CMD_REQUEST_MESSAGE else _REQUESTS[command]
            msgs = self._message(msg_id, p[1])
            return (ok, msgs, 0) if msgs else (mavlink.MAV_RESULT_DENIED, [], 0)
        if command == mavlink.MAV_CMD_IMAGE_START_CAPTURE:
            return self._start_capture(interval=p[1], count=int(p[2]), sequence=int(p[3]))
        if command == mavlink.MAV_CMD_IMAGE_STOP_CAPTURE:
            self._series_stop.set()
            return ok, [], 0
        if command == mavlink.MAV_CMD_SET_CAMERA_MODE:   # stills only: it records no video
            return (ok, [self._settings()], 0) if int(p[1]) == mavlink.CAMERA_MODE_IMAGE else (no, [], 0)
        if command in (mavlink.MAV_CMD_VIDEO_START_STREAMING, mavlink.MAV_CMD_VIDEO_STOP_STREAMING):
            if self.video is None or int(p[0]) not in (0, 1):
                return no, [], 0
            if command == mavlink.MAV_CMD_VIDEO_START_STREAMING:
                self.video.start()
            else:
                self.video.stop()
            return ok, [], 0
        if command in (mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, mavlink.MAV_CMD_REQUEST_PROTOCOL_VERSION):
            return None, [], 0   # the autopilot's to answer, when broadcast
        return no, [], 0

    def _message(self, msg_id: int, param2: float) -> list[Any]:
        if msg_id == mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            return [self._information()]
        if msg_id == mavlink.MAVLINK_MSG_ID_CAMERA_SETTINGS:
            return [self._settings()]
        if msg_id == mavlink.MAVLINK_MSG_ID_STORAGE_INFORMATION:
            return [self._storage()]
        if msg_id == mavlink.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS:
            return [self._capture_status()]
        if msg_id == mavlink.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
            with self._lock:
                found = self._captured.get(int(param2))
            return [found] if found is not None else []
        if self.video is not None and int(param2) in (0, 1):
            if msg_id == mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION:
                return [self.video.information()]
            if msg_id == mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_STATUS:
                return [self.video.status()]
        return []

    def _information(self) -> Any:
        focal, width_mm, height_mm = sensor_mm(self.model)
        flags = mavlink.CAMERA_CAP_FLAGS_CAPTURE_IMAGE | mavlink.CAMERA_CAP_FLAGS_HAS_MODES
        if self.video is not None:
            flags |= mavlink.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        uri = self.server.url(DEFINITION_PATH).encode() if self.server else b""
        return mavlink.MAVLink_camera_information_message(
            self._boot_ms(), _text(VENDOR, 32), _text(MODEL, 32), 0, focal, width_mm, height_mm,
            self.model.width, self.model.height, 0, flags, 1 if uri else 0, uri)

    def _settings(self) -> Any:
        return mavlink.MAVLink_camera_settings_message(self._boot_ms(), mavlink.CAMERA_MODE_IMAGE, math.nan, math.nan)

    def _storage(self) -> Any:
        total = self.files.keep_bytes / 2 ** 20
        return mavlink.MAVLink_storage_information_message(
            self._boot_ms(), 1, 1, mavlink.STORAGE_STATUS_READY, total, 0.0, total, math.nan, math.nan,
            mavlink.STORAGE_TYPE_OTHER, b"memory", mavlink.STORAGE_USAGE_FLAG_SET | mavlink.STORAGE_USAGE_FLAG_PHOTO)

    def _capture_status(self) -> Any:
        series = self._series is not None and self._series.is_alive()
        with self._lock:
            busy, count = self._pending > 0, self._index
        status = (3 if busy else 2) if series else (1 if busy else 0)
        return mavlink.MAVLink_camera_capture_status_message(self._boot_ms(), status, 0, 0.0, 0,
                                                             self.files.keep_bytes / 2 ** 20, count)

    # -------------------------------------------------------------- captures
    def _start_capture(self, interval: float, count: int, sequence: int) -> tuple[int, list[Any], int]:
        if count == 1:
            if sequence > 0 and sequence == self._last_sequence:   # our ACK was lost: the same image
                return mavlink.MAV_RESULT_ACCEPTED, [], max(0, self.images - 1)
            index = self.trigger()
            if index is None:
                return mavlink.MAV_RESULT_TEMPORARILY_REJECTED, [], 0
            self._last_sequence = sequence
            return mavlink.MAV_RESULT_ACCEPTED, [], index
        if not (math.isfinite(interval) and interval >= MIN_INTERVAL_S) or count < 0:
            return mavlink.MAV_RESULT_DENIED, [], 0
        self._series_stop.set()
        if self._series is not None:
            self._series.join(2.0)
        self._series_stop = threading.Event()
        self._series = threading.Thread(target=self._take_series, args=(interval, count, self._series_stop),
                                        name="camera-series", daemon=True)
        self._series.start()
        return mavlink.MAV_RESULT_ACCEPTED, [], self.images

    def _take_series(self, interval: float, count: int, stop: threading.Event) -> None:
        taken = 0
        while not stop.is_set() and (count == 0 or taken < count):
            self.trigger()
            taken += 1
            stop.wait(interval)

    def trigger(self) -> int | None:
        """Open the shutter now; the image's index, or None if too many wait to be rendered."""
        with self._lock:
            if self._pending >= MAX_PENDING:
                self.refused += 1
                return None
            self._pending += 1
            index = self._index
            self._index += 1
        utc = time.time()
        try:
            shot = self._expose()
            self._run(lambda: self._finish(index, shot, utc))
        except Exception as exc:  # noqa: BLE001 - shutting down, or the world could not expose
            self._finish(index, None, utc, f"{type(exc).__name__}: {exc}")
        return index

    def _finish(self, index: int, shot: Any, utc: float, failed: str = "") -> None:
        frame = None
        if not failed:
            try:
                frame = self._develop(shot)
            except Exception as exc:  # noqa: BLE001 - a failed image is reported as one, not a dead camera
                failed = f"{type(exc).__name__}: {exc}"
        if frame is not None:
            path = self.files.put_image(index, frame.png, frame.encoding)
            msg = captured_message(frame, index, utc, self.link.home, self.server.url(path) if self.server else "")
        else:
            print(f"warning: camera: image {index} failed: {failed}", flush=True)
            msg = mavlink.MAVLink_camera_image_captured_message(self._boot_ms(), int(utc * 1e6), 0, 0, 0, 0, 0,
                                                                [1.0, 0.0, 0.0, 0.0], index, 0, b"")
        with self._lock:
            self._pending -= 1
            self._captured[index] = msg
            for old in [i for i in self._captured if i <= index - KEEP_CAPTURED]:
                del self._captured[old]
        self._send(msg)


def captured_message(frame: Any, index: int, utc: float, home: tuple[float, float, float], url: str) -> Any:
    """CAMERA_IMAGE_CAPTURED for a CameraFrame (its published pose, in the floor's frame)."""
    lat, lon = ned_to_geo(frame.north_m, frame.east_m, home[0], home[1])
    q = camera_quaternion(frame.roll_rad, frame.pitch_rad, frame.yaw_rad)
    return mavlink.MAVLink_camera_image_captured_message(
        int(round(frame.time_s * 1000)) & 0xFFFFFFFF, int(utc * 1e6), 0, int(round(lat * 1e7)),
        int(round(lon * 1e7)), int(round((home[2] - frame.down_m) * 1000)), int(round(-frame.down_m * 1000)),
        list(q), index, 1, url.encode()[:205])
