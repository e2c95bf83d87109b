"""The MAVLink camera protocol, as a real drone's camera speaks it: the component's link
(`CameraLink`) and the source built on it."""
from __future__ import annotations

import queue
import threading
import time
import urllib.request
from typing import Any, Callable

from protocol.errors import MissionError, UavRobotsError
from protocol.messages import CameraFrame
from protocol.codec import decode
from protocol.transport import PendingRequest

from .base import (ACK_TIMEOUT_S, CAMERA_COMPONENT, CAMERA_TIMEOUT_S, FETCH_TIMEOUT_S, OUR_VENDOR, QUERY_TIMEOUT_S,
                   SOURCE_COMPONENT, SOURCE_SYSTEM, CameraSource, CameraSourceConfig, Answered, as_text, captured_pose,
                   file_beside, frame_from, image_size, pinhole, read_calibration)


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


class MavlinkSource(CameraSource):
    """The MAVLink camera protocol: a capture command per image, the file fetched over HTTP."""
    name = "the MAVLink camera"

    def __init__(self, cfg: CameraSourceConfig, home: tuple[float, float, float], timeout_s: float) -> None:
        self.home = home
        self.link = CameraLink(cfg.mavlink, timeout_s)
        info = self.link.information
        self._indexed = as_text(info.vendor_name) == OUR_VENDOR
        try:
            self.calibration = self._calibration(cfg.calibration, info)
        except (MissionError, UavRobotsError):
            self.link.close()
            raise
        self._sequence = 0
        self._claimed = 0
        self._lock = threading.Lock()

    def _calibration(self, given: str | None, info: Any) -> dict[str, Any]:
        beside = file_beside(as_text(info.cam_definition_uri), "calibration.json")
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
        return Answered(lambda: self._fetch(index, after))

    def _fetch(self, index: int | None, after: int) -> CameraFrame:
        msg = self.link.image(index, after, CAMERA_TIMEOUT_S)
        if msg.capture_result != 1:
            raise MissionError(f"the camera at {self.link.url} failed image {msg.image_index}")
        url = as_text(msg.file_url)
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
