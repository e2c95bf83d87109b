"""`uav-robots run --camera-source`: how the world's camera component and the UAV's camera source
are wired to each other (a MAVLink link on a free UDP port; for video, an RTP stream on another)."""
from __future__ import annotations

from typing import Callable

SOURCES = ("zenoh", "mavlink", "video")


def camera_wiring(source: str, free_udp: Callable[[], int]) -> tuple[list[str], list[str]]:
    """(the world's arguments, the UAV's) for camera source `source`."""
    if source == "zenoh":
        return [], []
    link = free_udp()
    world = ["--camera-mavlink", f"udpout:127.0.0.1:{link}"]
    uav = ["--camera-source", source, "--camera-mavlink", f"udpin:127.0.0.1:{link}"]
    if source == "video":
        world += ["--camera-video", f"udp://127.0.0.1:{free_udp()}"]   # the UAV finds it as a ground station does
    return world, uav

