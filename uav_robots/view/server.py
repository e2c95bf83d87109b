"""The view's web server: the standard library's threading HTTP server, Server-Sent Events for live updates.

Routes: `/` the page, `/map.png` the floor (drawn once), `/meta.json` the mode and map size, `/stream`
(live) an event stream of `FleetView` deltas every `PERIOD_S`, `/timeline.json` (replay) the whole
recorded mission. Each browser has its own thread; a slow one only delays its own stream, and since
it gets what changed since its last update, it skips ticks rather than queueing them.
"""
from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from uav_agent.visualize import FLOOR, SHELF

from .state import FleetView, Seen

PAGE = Path(__file__).with_name("page.html")
PERIOD_S = 0.1


def map_png(free: np.ndarray) -> bytes:
    """One pixel per cell: the browser scales it (nearest neighbour) to any size."""
    img = np.where(free[..., None], np.array(FLOOR, np.uint8), np.array(SHELF, np.uint8))
    return cv2.imencode(".png", img)[1].tobytes()


class ViewServer:
    def __init__(self, port: int, free: np.ndarray, view: FleetView | None = None,
                 timeline: dict[str, Any] | None = None, cell_m: float = 1.0, host: str = "127.0.0.1") -> None:
        self.view, self.timeline = view, timeline
        self._png = map_png(free)
        self._meta = json.dumps({"mode": "live" if view is not None else "replay",
                                 "width": int(free.shape[1]), "height": int(free.shape[0]), "cell_m": cell_m}).encode()
        self._stopping = threading.Event()
        self.httpd = ThreadingHTTPServer((host, port), self._handler())
        self.httpd.daemon_threads = True
        self.url = f"http://{host}:{self.httpd.server_address[1]}/"
        self._thread = threading.Thread(target=self.httpd.serve_forever, name="view", daemon=True)
        self._thread.start()

    def _handler(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:   # the mission's output stays the mission's
                pass

            def _send(self, body: bytes, ctype: str) -> None:
                self.send_response(200)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                path = self.path.split("?", 1)[0]
                if path in ("/", "/index.html"):
                    self._send(PAGE.read_bytes(), "text/html; charset=utf-8")
                elif path == "/map.png":
                    self._send(server._png, "image/png")
                elif path == "/meta.json":
                    self._send(server._meta, "application/json")
                elif path == "/timeline.json" and server.timeline is not None:
                    self._send(json.dumps(server.timeline, separators=(",", ":")).encode(), "application/json")
                elif path == "/stream" and server.view is not None:
                    self._stream()
                else:
                    self.send_error(404)

            def _stream(self) -> None:
                self.send_response(200)
                self.send_header("Content-Type", "text/event-stream")
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                seen = Seen()
                try:
                    while not server._stopping.is_set():
                        data = json.dumps(server.view.delta(seen), separators=(",", ":"))
                        self.wfile.write(f"data: {data}\n\n".encode())
                        self.wfile.flush()
                        time.sleep(PERIOD_S)
                except (BrokenPipeError, ConnectionResetError):
                    return

        return Handler

    def close(self) -> None:
        self._stopping.set()
        self.httpd.shutdown()
        self.httpd.server_close()


class Pump:
    """Feeds an observer's samples into a FleetView on a thread of its own (decoding off the Zenoh callback)."""

    def __init__(self, source: Callable[[int], list], view: FleetView) -> None:
        self._source, self.view = source, view
        self._stop = threading.Event()
        self._i = 0
        self._thread = threading.Thread(target=self._run, name="view-pump", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.drain()
            self._stop.wait(0.05)

    def drain(self) -> None:
        for s in self._source(self._i):
            self.view.apply(s.key, s.payload)
            self._i += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.drain()
