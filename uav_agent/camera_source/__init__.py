"""Where the UAV's images come from: the camera source it is given (`--camera-source`).

Perception never knows which: every source hands over a `CameraFrame` (the image, the
intrinsics and lens, the pose estimate at exposure), as `world/camera` answers it.

- `zenoh` (default): the world's `world/camera` query (docs/protocol.md). The shutter opens
  as the query arrives; `fence` (a `world/info` query on the same session) returns once it has.
- `mavlink`: the MAVLink camera protocol, as a real drone's camera speaks it: the camera
  component's HEARTBEAT, CAMERA_INFORMATION, then MAV_CMD_IMAGE_START_CAPTURE per image; its
  COMMAND_ACK says the shutter opened; CAMERA_IMAGE_CAPTURED gives the pose at exposure
  (lat/lon/alt, mapped to the floor's frame by the site's origin in `WorldInfo`; the camera's
  quaternion) and the file's URL, fetched over HTTP. The lens and the estimate's sigmas come
  from a calibration (`--camera-calibration`, else the `calibration.json` beside the camera's
  definition file, else the pinhole CAMERA_INFORMATION states).
- `video`: the newest frame of an H.264 RTP stream (the stream the camera component announces
  in VIDEO_STREAM_INFORMATION, or `--camera-video`), with the pose from the autopilot's
  telemetry when the frame arrived; the second frame to arrive after the request is taken, so
  it was rendered after it. Regions of interest are not asked of MAVLink or video cameras: they
  send whole images, which perception understands.
"""
from __future__ import annotations

from typing import Callable

from protocol.keys import Keys
from protocol.messages import WorldInfo
from protocol.transport import Transport

from .base import CameraSource, CameraSourceConfig, Pose
from .mavlink_source import MavlinkSource
from .video_source import VideoSource
from .zenoh_source import ZenohSource


def open_camera_source(cfg: CameraSourceConfig, transport: Transport, keys: Keys, info: WorldInfo,
                       next_seq: Callable[[], int], pose: Callable[[], Pose],
                       timeout_s: float = 30.0) -> CameraSource:
    """The source `cfg` names; the floor's origin is the site's (`info`), as the UAV's frame is."""
    cfg.check()
    if cfg.kind == "mavlink":
        return MavlinkSource(cfg, (info.home_lat, info.home_lon, info.home_alt_m), timeout_s)
    if cfg.kind == "video":
        return VideoSource(cfg, pose, timeout_s)
    return ZenohSource(transport, keys, next_seq)
