"""The world's `world/camera` query over Zenoh (the default source)."""
from __future__ import annotations

from typing import Any, Callable

from protocol.keys import Keys
from protocol.messages import CameraFrame, CameraRequest, WorldInfoRequest
from protocol.codec import encode
from protocol.transport import PendingRequest, Transport

from .. import world_query
from .base import CAMERA_TIMEOUT_S, QUERY_TIMEOUT_S, CameraSource


class ZenohSource(CameraSource):
    """The world's `world/camera` query."""
    name = "the world's camera"

    def __init__(self, transport: Transport, keys: Keys, next_seq: Callable[[], int]) -> None:
        self.transport, self.keys, self._next = transport, keys, next_seq

    def frame(self, calibration_only: bool = False) -> CameraFrame:
        return world_query.query(self.transport, self.keys.camera,
                                 CameraRequest(calibration_only=calibration_only, seq=self._next()), CameraFrame,
                                 "camera", CAMERA_TIMEOUT_S)

    def start(self, roi: Any = None) -> PendingRequest:
        area = {} if roi is None else {"roi_x": roi.x, "roi_y": roi.y, "roi_width": roi.width,
                                       "roi_height": roi.height}
        return self.transport.request_start(self.keys.camera, encode(CameraRequest(seq=self._next(), **area)),
                                            CAMERA_TIMEOUT_S)

    def fence(self) -> None:
        self.transport.request(self.keys.world_info, encode(WorldInfoRequest(seq=self._next())), QUERY_TIMEOUT_S)
