"""The camera's files over HTTP, as a real MAVLink camera serves them: the images it took (the
`file_url` of CAMERA_IMAGE_CAPTURED), its definition file (CAMERA_INFORMATION's
`cam_definition_uri`), its calibration beside it, and the video stream's SDP.

A small threaded `http.server` on the camera's bind address (loopback unless opened on
purpose). Images are kept in memory, newest last, up to `keep_bytes` (a camera's card that
overwrites its oldest files): an older URL then answers 404.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from protocol.errors import MissionError

KEEP_BYTES = 512 * 1024 * 1024   # about 150 of the 12 MP camera's JPEG images
CONTENT_TYPES = {"jpeg": "image/jpeg", "png": "image/png", "json": "application/json",
                 "xml": "application/xml", "sdp": "application/sdp"}


class CameraFiles:
    """What the server answers: fixed documents by path, and the images by index."""

    def __init__(self, keep_bytes: int = KEEP_BYTES) -> None:
        self.keep_bytes = keep_bytes
        self._docs: dict[str, tuple[bytes, str]] = {}
        self._images: OrderedDict[str, tuple[bytes, str]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def put_doc(self, path: str, data: bytes, kind: str) -> None:
        with self._lock:
            self._docs[path] = (data, CONTENT_TYPES[kind])

    def put_image(self, index: int, data: bytes, encoding: str) -> str:
        """Keep image `index`; its path on the server."""
        path = f"/images/{index:06d}.{'jpg' if encoding == 'jpeg' else 'png'}"
        with self._lock:
            self._images[path] = (data, CONTENT_TYPES[encoding])
            self._bytes += len(data)
            while self._bytes > self.keep_bytes and len(self._images) > 1:
                _, (old, _) = self._images.popitem(last=False)
                self._bytes -= len(old)
        return path

    def get(self, path: str) -> tuple[bytes, str] | None:
        with self._lock:
            return self._docs.get(path) or self._images.get(path)


def _handler(files: CameraFiles) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        server_version = "uav-robots-camera"

        def do_GET(self) -> None:   # noqa: N802 - http.server's name
            found = files.get(self.path.split("?", 1)[0])
            if found is None:
                self.send_error(404, "no such file on the camera")
                return
            data, kind = found
            self.send_response(200)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def log_message(self, *args: object) -> None:   # one line per request would flood the world's log
            pass

    return Handler


class FileServer:
    """`files` served on http://host:port until `close()`; port 0 takes a free one."""

    def __init__(self, files: CameraFiles, host: str = "127.0.0.1", port: int = 0) -> None:
        try:
            self._server = ThreadingHTTPServer((host, port), _handler(files))
        except OSError as exc:
            raise MissionError(f"camera: cannot serve its files on {host}:{port}: {exc}") from None
        self._server.daemon_threads = True
        bound_host, self.port = self._server.server_address[:2]
        # A server on every address is reached, from this machine, on loopback.
        self.host = "127.0.0.1" if bound_host in ("0.0.0.0", "") else bound_host
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="camera-http", daemon=True)
        self._thread.start()

    def url(self, path: str) -> str:
        return f"http://{self.host}:{self.port}{path}"

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(2.0)
