"""The UAV's images for observers (live views, recorders): downscaled JPEG on `<fleet>/uav/frame`.

Decoding a 4000x3000 PNG takes a tenth of a second (a JPEG is decoded at a fraction of its size), so it happens on a thread of its own that keeps only
the newest image: an observer may miss an image, the mission never waits for one.
"""
from __future__ import annotations

import dataclasses
import threading
from typing import Callable

from protocol.messages import CameraFrame

PREVIEW_SIDE = 640      # px, the longer side: enough to see robots and markers in a browser or Foxglove
JPEG_QUALITY = 80


def preview_frame(frame: CameraFrame, side: int = PREVIEW_SIDE) -> CameraFrame:
    """The same frame (pose, time, seq) with its image as a JPEG no longer than `side`; intrinsics scaled."""
    # Imported here: the UAV must open its Zenoh router before paying for OpenCV (robots wait for it).
    import cv2
    import numpy as np

    # A JPEG decodes straight to 1/2, 1/4 or 1/8 of its size (libjpeg scales in the DCT), a
    # fraction of the cost of the 12 MP decode; no smaller than the preview, which INTER_AREA makes.
    flag = cv2.IMREAD_COLOR
    for factor, reduced in ((8, cv2.IMREAD_REDUCED_COLOR_8), (4, cv2.IMREAD_REDUCED_COLOR_4),
                            (2, cv2.IMREAD_REDUCED_COLOR_2)):
        if max(frame.width, frame.height) >= factor * side:
            flag = reduced
            break
    image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), flag)
    if image is None:
        raise ValueError("the camera frame's image does not decode")
    s = min(1.0, side / max(image.shape[:2]))
    if s < 1.0:
        image = cv2.resize(image, (max(1, round(image.shape[1] * s)), max(1, round(image.shape[0] * s))),
                           interpolation=cv2.INTER_AREA)
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("the preview does not encode as JPEG")
    h, w = image.shape[:2]
    sx, sy = w / frame.width, h / frame.height
    return dataclasses.replace(frame, width=w, height=h, fx=frame.fx * sx, fy=frame.fy * sy, cx=frame.cx * sx,
                               cy=frame.cy * sy, png=jpeg.tobytes(), encoding="jpeg")


class Previewer:
    """Publishes the newest submitted frame's preview through `publish`, off the caller's thread."""

    def __init__(self, publish: Callable[[CameraFrame], None]) -> None:
        self._publish = publish
        self._latest: CameraFrame | None = None
        self._cv = threading.Condition()
        self._closed = False
        self._cut = False                     # closed and waited for: nothing is published any more
        self._publishing = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="preview", daemon=True)
        self._thread.start()

    def submit(self, frame: CameraFrame) -> None:
        with self._cv:
            self._latest = frame
            self._cv.notify()

    def _run(self) -> None:
        while True:
            with self._cv:
                while self._latest is None and not self._closed:
                    self._cv.wait()
                frame, self._latest = self._latest, None
            if frame is None:
                return
            try:
                preview = preview_frame(frame)
                with self._publishing:
                    if self._cut:
                        return
                    self._publish(preview)
            except Exception:  # noqa: BLE001 - a preview lost must never end the mission
                pass

    def close(self, timeout_s: float = 2.0) -> None:
        """Publish what is pending (the last image of a mission matters to a recorder), then stop. After
        `timeout_s` (a loaded machine, a 12 MP decode) the pending preview is dropped: once this returns
        nothing is published, so no frame follows the MissionEnd sent next."""
        with self._cv:
            self._closed = True
            self._cv.notify()
        self._thread.join(timeout_s)
        with self._publishing:
            self._cut = True
