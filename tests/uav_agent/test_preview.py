"""The observers' preview of a camera frame: small, the same picture, intrinsics scaled."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim_world.camera import CameraModel, Scene, encode_frame, render
from uav_agent.preview import preview_frame


@pytest.mark.parametrize("jpeg_quality", [0, 90])
def test_a_12_mp_frame_previews_as_the_same_picture_at_640_px(jpeg_quality):
    free = np.ones((60, 80), bool)
    free[10:50:6, 5:75] = False
    model = CameraModel(width=4000, height=3000, jpeg_quality=jpeg_quality)
    pose = (-30.0, 40.0, -45.0, 0.0)
    image = render(Scene(free, {7: (20, 20)}, [(30, 30)]), pose, model, 1.0)
    frame = encode_frame(image, pose, model, 1.0)
    small = preview_frame(frame)
    assert (small.width, small.height, small.encoding) == (640, 480, "jpeg")
    assert small.fx == pytest.approx(model.fx * 640 / 4000) and small.cy == pytest.approx(model.cy * 480 / 3000)
    seen = cv2.imdecode(np.frombuffer(small.png, np.uint8), cv2.IMREAD_COLOR).astype(float)
    expected = cv2.resize(image, (640, 480), interpolation=cv2.INTER_AREA).astype(float)
    assert np.abs(seen - expected).mean() < 3.0
