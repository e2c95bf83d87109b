"""Surveyed landmarks: where they are placed, and that a camera really sees them there."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from protocol.codec import decode, encode
from protocol.errors import MapError
from protocol.messages import WorldInfo, WorldInfoRequest
from protocol.run_spec import SceneSpec
from protocol.transport import MemoryBus, MemoryTransport
from scenarios.landmarks import LANDMARK_IDS, place_landmarks
from scenarios.maps import random_map, resolve_map
from sim_world.camera import CameraModel, Scene, floor_homography, render
from sim_world.config import DRONE_CAMERA, WorldConfig
from sim_world.service import World
from uav_agent.survey import survey_poses

CELL = 1.0


def _blocks(marks, free):
    """(x0, y0, x1, y1) cell ranges of each landmark's block."""
    h, w = free.shape
    b = marks.block_cells
    for (_, e, n) in marks.landmarks:
        u, v = e / CELL, -n / CELL
        yield round(u - b / 2), round(v - b / 2), round(u + b / 2), round(v + b / 2)


@pytest.mark.parametrize("spec", ["warehouse-small", "warehouse-450", "random:width=64,height=64,density=0.2",
                                  "random:width=40,height=30,density=0"])
def test_landmarks_sit_on_shelves_or_outside_the_grid_and_never_overlap(spec):
    _, free = resolve_map(spec, 0)
    marks = place_landmarks(free, CELL)
    h, w = free.shape
    taken = np.zeros((h + 8, w + 8), bool)
    inside = 0
    for x0, y0, x1, y1 in _blocks(marks, free):
        if 0 <= x0 and x1 <= w and 0 <= y0 and y1 <= h:
            inside += 1
            assert not free[y0:y1, x0:x1].any(), f"a landmark on floor cells {x0, y0}..{x1, y1}"
        else:   # the ring: wholly outside the grid
            assert x1 <= 0 or x0 >= w or y1 <= 0 or y0 >= h, f"a ring landmark overlaps the grid at {x0, y0}"
        assert not taken[y0 + 4:y1 + 4, x0 + 4:x1 + 4].any(), "two landmarks overlap"
        taken[y0 + 4:y1 + 4, x0 + 4:x1 + 4] = True
    if (~free).any() and spec != "warehouse-small":
        assert inside > 0
    assert all(0 <= lid < LANDMARK_IDS for lid, _, _ in marks.landmarks)


def test_placement_is_deterministic_unique_on_small_maps_and_periodic_far_apart_on_big_ones():
    _, free = resolve_map("warehouse-450", 0)
    a, b = place_landmarks(free, CELL), place_landmarks(free.copy(), CELL)
    assert a == b and a.family == "DICT_5X5_1000" and a.size_m == 1.5
    pos: dict[int, list[tuple[float, float]]] = {}
    for lid, e, n in a.landmarks:
        pos.setdefault(lid, []).append((e, n))
    nearest = min(np.hypot(p[0] - q[0], p[1] - q[1]) for ps in pos.values() for i, p in enumerate(ps)
                  for q in ps[i + 1:])
    assert nearest >= 300, f"two landmarks with one id only {nearest} m apart"
    small = place_landmarks(resolve_map("warehouse-small")[1], CELL)
    assert len({lid for lid, _, _ in small.landmarks}) == len(small.landmarks)
    # The spacing is a parameter: a denser lattice places more markers.
    assert len(place_landmarks(free, CELL, spacing=8).landmarks) > len(a.landmarks)
    # Scattered obstacles: single cells carry smaller markers, one size for the whole map.
    scattered = place_landmarks(random_map(64, 64, 0.2, 0), CELL)
    assert scattered.block_cells == 1 and scattered.size_m == 0.75


def test_bad_landmark_arguments_are_refused():
    with pytest.raises(MapError):
        place_landmarks(np.ones((4, 4)), CELL)
    with pytest.raises(MapError):
        place_landmarks(np.ones((4, 4), bool), CELL, spacing=2)
    with pytest.raises(MapError):
        place_landmarks(np.ones((4, 4), bool), 0.0)


@pytest.mark.parametrize("spec", ["warehouse-small", "warehouse-450"])
def test_every_survey_footprint_holds_several_landmarks(spec):
    _, free = resolve_map(spec, 0)
    h, w = free.shape
    marks = place_landmarks(free, CELL)
    centres = marks.centres_cells(CELL)
    model = CameraModel(**DRONE_CAMERA)
    corners = np.array([[[0, 0]], [[model.width - 1, 0]], [[0, model.height - 1]],
                        [[model.width - 1, model.height - 1]]], dtype=np.float64)
    poses = survey_poses(w, h, CELL, model)
    assert poses
    for n, e, alt in poses:
        floor = cv2.perspectiveTransform(corners, np.linalg.inv(floor_homography((n, e, -alt, 0.0), model, CELL)))
        lo, hi = floor.reshape(-1, 2).min(axis=0) + 1, floor.reshape(-1, 2).max(axis=0) - 1
        seen = np.all((centres >= lo) & (centres <= hi), axis=1).sum()
        assert seen >= 6, f"only {seen} landmarks in the footprint from {(n, e, alt)}"


def _detect(image: np.ndarray, family: str) -> dict[int, np.ndarray]:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family)), params)
    corners, ids, _ = det.detectMarkers(image)
    return {} if ids is None else {int(i): c[0] for i, c in zip(ids.ravel(), corners)}


@pytest.mark.parametrize("yaw", [0.0, 0.7])
def test_a_rendered_landmark_is_detected_at_its_published_position_and_size(yaw):
    _, free = resolve_map("warehouse:blocks_x=3,blocks_y=6", 0)
    marks = place_landmarks(free, CELL)
    h, w = free.shape
    model = CameraModel(width=1600, height=1200)
    pose = (-h / 2, w / 2, -16.0, yaw)
    image = render(Scene(free, landmarks=marks), pose, model, CELL)
    found = _detect(image, marks.family)
    assert len(found) >= 6
    H = floor_homography(pose, model, CELL)
    by_id = {lid: (e, n) for lid, e, n in marks.landmarks}
    s = marks.size_m / 2
    for lid, quad in found.items():
        e, n = by_id[lid]
        # Corners in OpenCV's order (top-left, top-right, bottom-right, bottom-left), top = north.
        truth = np.array([[[e - s, n + s]], [[e + s, n + s]], [[e + s, n - s]], [[e - s, n - s]]])
        uv = np.concatenate([truth[..., :1] / CELL, -truth[..., 1:] / CELL], axis=2)
        expect = cv2.perspectiveTransform(uv, H).reshape(-1, 2)
        assert np.abs(quad - expect).max() < 1.0, f"landmark {lid}: {quad} vs {expect}"
    # Robots' dictionary does not read landmarks.
    assert _detect(image, "DICT_4X4_1000") == {}


def test_the_world_publishes_its_landmarks_when_the_camera_asks_for_them(tmp_path):
    _, free = resolve_map("warehouse-small")
    bus = MemoryBus()
    for spacing, expect in ((0, False), (12, True)):
        world = World(WorldConfig(fleet="t", robots=2, mavlink=None, scene=SceneSpec(landmark_spacing=spacing)),
                      MemoryTransport(bus))
        world.start()
        client = MemoryTransport(bus)
        try:
            info = decode(client.request(world.keys.world_info, encode(WorldInfoRequest()), 5)[0], WorldInfo)
        finally:
            client.close()
            world.close()
        if expect:
            assert info.landmark_family == "DICT_5X5_1000" and info.landmark_size_m == 1.5
            assert info.landmarks == place_landmarks(free, CELL).landmarks
        else:
            assert info.landmark_family == "" and info.landmarks == []
