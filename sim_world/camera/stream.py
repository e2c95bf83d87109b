"""The camera's live video, the way PX4's simulated cameras stream it: H.264 over RTP/UDP to a
ground station's port (QGroundControl listens on 5600), announced by VIDEO_STREAM_INFORMATION.

The frames are the camera's own rendering (the same scene, lens and degradations) on a sensor
scaled down to the stream's width, from the vehicle's true pose at each frame; PyAV's libx264
(ultrafast, zero latency, a key frame every second with its SPS/PPS, so a receiver joining late
decodes within a second) and FFmpeg's RTP muxer (payload type 96, as the SDP says). It is off
unless `--camera-video` is given: a frame costs a render and an encode on the world's CPU.

PyAV (`pip install 'uav-robots[video]'`) is imported only when a stream starts.
"""
from __future__ import annotations

import dataclasses
import json
import math
import threading
import time
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, Callable
from urllib.parse import parse_qs, urlsplit

from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import UavRobotsError

from .capture import VehicleView, view_image
from .mavlink_camera import calibration
from .model import CameraModel

DEFAULT_PORT = 5600          # QGroundControl's UDP video port
DEFAULT_FPS = 5.0
DEFAULT_WIDTH = 1280
MAX_FPS, MAX_WIDTH = 30.0, 1920
BITS_PER_PIXEL = 0.25        # per frame: a robot's marker module is 2-3 px, which a starved encoder smears
PAYLOAD_TYPE = 96
SDP_PATH, VIDEO_CALIBRATION_PATH = "/video/stream.sdp", "/video/calibration.json"


@dataclass(frozen=True)
class VideoConfig:
    """Where the stream goes, `udp://HOST:PORT[?fps=F&width=W]`: the receiver's address."""
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    fps: float = DEFAULT_FPS
    width: int = DEFAULT_WIDTH

    @property
    def uri(self) -> str:
        return f"udp://{self.host}:{self.port}"


def video_config(text: str) -> VideoConfig:
    """`--camera-video` text -> VideoConfig; one line naming the problem if it is not one."""
    why = "give udp://HOST:PORT[?fps=F&width=W]"
    try:
        url = urlsplit(text)
        port = url.port
        query = parse_qs(url.query, strict_parsing=bool(url.query))
    except ValueError:
        raise UavRobotsError(f"--camera-video {text!r}: {why}") from None
    if url.scheme != "udp" or not url.hostname or not port or url.path not in ("", "/"):
        raise UavRobotsError(f"--camera-video {text!r}: {why}")
    unknown = set(query) - {"fps", "width"}
    if unknown:
        raise UavRobotsError(f"--camera-video {text!r}: unknown option(s) {', '.join(sorted(unknown))} ({why})")
    try:
        fps = float(query.get("fps", [DEFAULT_FPS])[-1])
        width = int(query.get("width", [DEFAULT_WIDTH])[-1])
    except ValueError:
        raise UavRobotsError(f"--camera-video {text!r}: fps and width must be numbers") from None
    if not (math.isfinite(fps) and 0.2 <= fps <= MAX_FPS) or not 64 <= width <= MAX_WIDTH:
        raise UavRobotsError(f"--camera-video {text!r}: fps must be in [0.2, {MAX_FPS:g}] and width in "
                             f"[64, {MAX_WIDTH}]")
    return VideoConfig(url.hostname, port, fps, width)


def scaled_model(model: CameraModel, width: int) -> CameraModel:
    """The same camera on a sensor `width` pixels wide (even sides, as H.264's 4:2:0 needs): the
    intrinsics and the blur scaled with it, pixel centres kept (OpenCV's convention)."""
    width = min(width, model.width) // 2 * 2
    s = width / model.width
    height = max(16, round(model.height * s) // 2 * 2)
    sy = height / model.height
    return dataclasses.replace(model, width=width, height=height, fx=model.fx * s, fy=model.fy * sy,
                               cx=(model.cx + 0.5) * s - 0.5, cy=(model.cy + 0.5) * sy - 0.5,
                               blur_sigma=model.blur_sigma * s)


def sdp(cfg: VideoConfig) -> str:
    """The session description a receiver (ffmpeg, VLC, our UAV) opens the stream with."""
    return (f"v=0\r\no=- 0 0 IN IP4 {cfg.host}\r\ns=uav-robots camera\r\nc=IN IP4 {cfg.host}\r\nt=0 0\r\n"
            f"m=video {cfg.port} RTP/AVP {PAYLOAD_TYPE}\r\na=rtpmap:{PAYLOAD_TYPE} H264/90000\r\n"
            f"a=fmtp:{PAYLOAD_TYPE} packetization-mode=1\r\n")


def require_pyav() -> Any:
    try:
        import av
    except ImportError:
        raise UavRobotsError("the camera's video needs PyAV: pip install 'uav-robots[video]'") from None
    return av


class VideoStream:
    """Frames rendered by `render()` (a BGR image of `model`'s size) at `cfg.fps`, encoded and
    sent while started."""

    def __init__(self, cfg: VideoConfig, model: CameraModel, render: Callable[[CameraModel], Any],
                 bind_host: str = "127.0.0.1") -> None:
        require_pyav()
        self.cfg, self.model, self._render, self._bind = cfg, scaled_model(model, cfg.width), render, bind_host
        self.bitrate = int(BITS_PER_PIXEL * self.model.width * self.model.height * cfg.fps)
        self.frames = 0
        self.error = ""
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False

    def describe(self) -> str:
        return f"H.264 RTP {self.cfg.uri} {self.model.width}x{self.model.height} at {self.cfg.fps:g} fps"

    def publish(self, files: Any, server: Any) -> None:
        """Its SDP and its scaled calibration on the camera's file server."""
        files.put_doc(SDP_PATH, sdp(self.cfg).encode(), "sdp")
        files.put_doc(VIDEO_CALIBRATION_PATH, json.dumps(calibration(self.model)).encode(), "json")

    @property
    def running(self) -> bool:
        with self._lock:
            return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        with self._lock:
            if self._closed or (self._thread is not None and self._thread.is_alive()):
                return
            self._stop = threading.Event()
            self._thread = threading.Thread(target=self._loop, args=(self._stop,), name="camera-video", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        with self._lock:
            thread, self._thread = self._thread, None
            self._stop.set()
        if thread is not None:
            thread.join(5.0)

    def close(self) -> None:
        with self._lock:
            self._closed = True
        self.stop()

    def information(self) -> Any:
        flags = mavlink.VIDEO_STREAM_STATUS_FLAGS_RUNNING if self.running else 0
        return mavlink.MAVLink_video_stream_information_message(
            1, 1, mavlink.VIDEO_STREAM_TYPE_RTPUDP, flags, self.cfg.fps, self.model.width, self.model.height,
            self.bitrate, 0, self._hfov_deg(), b"nadir", self.cfg.uri.encode(), mavlink.VIDEO_STREAM_ENCODING_H264)

    def status(self) -> Any:
        flags = mavlink.VIDEO_STREAM_STATUS_FLAGS_RUNNING if self.running else 0
        return mavlink.MAVLink_video_stream_status_message(1, flags, self.cfg.fps, self.model.width,
                                                           self.model.height, self.bitrate, 0, self._hfov_deg())

    def _hfov_deg(self) -> int:
        return round(math.degrees(2 * math.atan(self.model.width / 2 / self.model.fx)))

    def _loop(self, stop: threading.Event) -> None:
        av = require_pyav()
        try:
            out = av.open(f"rtp://{self.cfg.host}:{self.cfg.port}?localaddr={self._bind}&pkt_size=1200", "w",
                          format="rtp")
        except Exception as exc:  # noqa: BLE001 - FFmpeg's errors: said once, the world goes on
            self.error = f"cannot open {self.cfg.uri}: {exc}"
            print(f"warning: camera video: {self.error}", flush=True)
            return
        period = 1.0 / self.cfg.fps
        try:
            keyint = max(1, round(self.cfg.fps))
            enc = out.add_stream("libx264", rate=Fraction(self.cfg.fps).limit_denominator(1000), options={
                "preset": "ultrafast", "tune": "zerolatency",
                "x264-params": f"keyint={keyint}:min-keyint={keyint}:repeat-headers=1"})
            enc.width, enc.height, enc.pix_fmt, enc.bit_rate = self.model.width, self.model.height, "yuv420p", self.bitrate
            enc.codec_context.time_base = Fraction(1, 90000)
            t0 = time.monotonic()
            n = 0
            while not stop.is_set():
                image = self._render(self.model)
                frame = av.VideoFrame.from_ndarray(image, format="bgr24")
                frame.pts = int((time.monotonic() - t0) * 90000)
                frame.time_base = Fraction(1, 90000)
                for packet in enc.encode(frame):
                    self._mux(out, packet)
                self.frames += 1
                n += 1
                stop.wait(max(0.0, t0 + n * period - time.monotonic()))
        except Exception as exc:  # noqa: BLE001 - a stream fault must not kill the world
            self.error = f"{type(exc).__name__}: {exc}"
            print(f"warning: camera video stopped: {self.error}", flush=True)
        finally:
            try:
                out.close()
            except Exception:  # noqa: BLE001 - closing a broken muxer
                pass

    @staticmethod
    def _mux(out: Any, packet: Any) -> None:
        try:
            out.mux(packet)
        except OSError:   # nobody listening yet (ICMP unreachable): a datagram lost, as UDP loses them
            pass


def render_view(expose: Callable[[], tuple]) -> Callable[[CameraModel], Any]:
    """A video frame renderer over the world's `expose()` (capture_frame's arguments)."""
    def render(model: CameraModel) -> Any:
        scene, view, _model, cell_size_m, _estimator, _t, _seq, seed = expose()
        return view_image(scene, VehicleView(*view), model, cell_size_m, seed)
    return render
