"""Our world in the suite's process, watched: when each image's shutter opens, and the images it sends."""
from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

from protocol.messages import Record
from protocol.transport import IncomingQuery

from ..hub import Hub
from .options import RTL_SEEN_S, UavOptions
from .processes import free_udp_port


@dataclass(frozen=True)
class Shutter:
    """An image's exposure as the world fixed it: when, and how settled the floor was."""
    at: float            # monotonic time
    judged: int          # the last tick the world judged
    heard: int           # the last Tick the world heard from the UAV
    open_tick: int | None  # a tick whose moves were being collected (None: none)

    @property
    def settled(self) -> bool:
        return self.open_tick is None and self.judged >= self.heard


class _Tap:
    """An incoming camera query whose reply is also handed to `sink` (the world's image, as sent)."""

    def __init__(self, query: IncomingQuery, sink: Callable[[bytes], None]) -> None:
        self._query, self._sink = query, sink

    def reply(self, payload: bytes) -> None:
        self._sink(payload)
        self._query.reply(payload)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._query, name)


class Site:
    """Our world in this process: the floor's truth, the move service, the camera and the MAVLink vehicle."""

    def __init__(self, hub: Hub, opts: UavOptions) -> None:
        from sim_world.config import WorldConfig
        from sim_world.service import World

        self.mavlink_port = free_udp_port()
        self.gcs_port = free_udp_port()   # the operator's link (the flight link answers the UAV only)
        self.shutters: list[Shutter] = []
        self.images: list[dict[str, Any]] = []      # the header of every image the world sent
        self._lock = threading.Lock()
        self.world = World(WorldConfig(fleet=hub.fleet, map=opts.map, robots=opts.robots, seed=opts.seed,
                                       connectivity=opts.connectivity, time_scale=opts.time_scale,
                                       mavlink=f"udpout:127.0.0.1:{self.mavlink_port}",
                                       gcs=f"udpin:127.0.0.1:{self.gcs_port}", connect=[hub.endpoint]))
        # Watched, not changed: when each shutter opens (how settled the floor is then), and what is sent.
        exposure, render = self.world.exposure, self.world._render_reply
        self.world.exposure = lambda: (self._shutter(), exposure())[1]
        self.world._render_reply = lambda q, shot, *rest: render(_Tap(q, self._sent), shot, *rest)
        try:
            self.world.start()
        except BaseException:
            self.world.close()
            raise

    def _shutter(self) -> None:
        desk = self.world.desk
        if desk is None:
            return
        with desk.cv:
            shot = Shutter(time.monotonic(), desk.judge.tick, desk.seen, desk.tick)
        with self._lock:
            self.shutters.append(shot)

    def _sent(self, payload: bytes) -> None:
        head = bytes(payload).split(b"\x00", 1)[0]
        try:
            with self._lock:
                self.images.append(json.loads(head))
        except ValueError:
            pass

    @property
    def truth(self):
        return self.world.truth

    def record(self) -> Record:
        return self.world.record()

    def vehicle(self) -> dict[str, Any] | None:
        return self.world.vehicle_dict()

    def command_rtl(self) -> float | None:
        """A ground station on the vehicle's ground-station link commands Return To Launch, as an operator's
        QGroundControl or a failsafe would; returns when the vehicle switched (None: it did not)."""
        from pymavlink import mavutil

        vehicle = self.world.vehicle
        if vehicle is None:
            return None
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{self.gcs_port}", source_system=250)
        try:
            gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
            deadline = time.monotonic() + RTL_SEEN_S
            while time.monotonic() < deadline:
                if vehicle.mode.name == "RTL":
                    return time.monotonic()
                time.sleep(0.02)
            return None
        finally:
            gcs.close()

    def close(self) -> None:
        self.world.close()
