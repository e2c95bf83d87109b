"""The newest frame of an H.264 RTP stream, with the pose from the autopilot's telemetry."""
from __future__ import annotations

import math
import os
import tempfile
import threading
import time
import urllib.request
from typing import Any, Callable
from urllib.parse import urlsplit

from protocol.errors import MissionError, UavRobotsError
from protocol.messages import CameraFrame
from protocol.codec import decode
from protocol.transport import PendingRequest

from .base import (CAMERA_TIMEOUT_S, FETCH_TIMEOUT_S, VIDEO_FRAME_TIMEOUT_S, CameraSource, CameraSourceConfig, Pose,
                   Answered, as_text, file_beside, frame_from, port, read_calibration, require_pyav)
from .mavlink_source import CameraLink


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
                stream = stream or as_text(info.uri)
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
        uri = as_text(self.link.information.cam_definition_uri) if self.link else ""
        beside = file_beside(uri, "video/calibration.json")
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
        return Answered(lambda: frame)

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


def sdp_file(stream: str) -> tuple[str, bool]:
    """(an SDP file describing `stream`, whether it is ours to delete). `udp://HOST:PORT` is taken
    as QGroundControl takes it: RTP, H.264, payload type 96."""
    url = urlsplit(stream)
    if url.scheme == "udp":
        text = (f"v=0\r\no=- 0 0 IN IP4 {url.hostname}\r\ns=camera\r\nc=IN IP4 {url.hostname}\r\nt=0 0\r\n"
                f"m=video {port(url)} RTP/AVP 96\r\na=rtpmap:96 H264/90000\r\na=fmtp:96 packetization-mode=1\r\n")
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
