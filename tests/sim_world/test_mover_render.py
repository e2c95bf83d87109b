"""The camera renders people, forklifts and pallets: no marker, a look of each kind's own, over
whatever their cell shows, and at a few draws each of only those in view.

Images are really rendered (the ideal camera, and the realistic one's lens, lighting, vignetting,
noise and JPEG) and read back through OpenCV.
"""
from __future__ import annotations

import dataclasses
import importlib

import cv2
import numpy as np
import pytest

from protocol.errors import MapError
from scenarios.maps import place, resolve_map
from sim_world.camera import PRESETS, CameraModel, Scene, camera_frame, cell_centre_ned, render
from sim_world.camera.encode import encode_frame
from sim_world.camera.render import (FORK_TINE_BGR, FORKLIFT_BGR, GOAL_BGR, OUTSIDE_BGR, PALLET_BGR, PERSON_BGR,
                                     SHELF_BGR)
from sim_world.movers import FORKLIFT, PALLET, PERSON

CELL = 1.0
KINDS = (PERSON, FORKLIFT, PALLET)
DRAWN = {PERSON: PERSON_BGR, FORKLIFT: FORKLIFT_BGR, PALLET: PALLET_BGR}


def hsv(bgr) -> tuple[int, int, int]:
    return tuple(int(v) for v in cv2.cvtColor(np.uint8([[bgr]]), cv2.COLOR_BGR2HSV)[0, 0])


def grey(bgr) -> int:
    return int(cv2.cvtColor(np.uint8([[bgr]]), cv2.COLOR_BGR2GRAY)[0, 0])


def hue_gap(a: int, b: int) -> int:
    return min(abs(a - b), 180 - abs(a - b))


def pixel_of(model: CameraModel, pose, u: float, v: float) -> tuple[int, int]:
    """The pixel a level camera at `pose` sees floor point (u, v) at (cells)."""
    from sim_world.camera import floor_homography
    x, y, z = floor_homography(pose, model, CELL) @ [u, v, 1.0]
    return round(x / z), round(y / z)


def test_a_scene_takes_movers_of_the_three_kinds_on_its_grid_only():
    free = np.ones((4, 5), bool)
    assert Scene(free).movers == ()
    Scene(free, movers=((PERSON, (0, 0)), (FORKLIFT, (4, 3)), (PALLET, (2, 1))))
    with pytest.raises(MapError, match="kind 'robot'"):
        Scene(free, movers=(("robot", (1, 1)),))
    with pytest.raises(MapError, match=r"forklift at \(5, 0\) is off the 5x4 grid"):
        Scene(free, movers=((FORKLIFT, (5, 0)),))


def test_the_kinds_look_unlike_each_other_and_everything_else_on_the_floor():
    """Each a saturated hue of its own, far from the goals' green and the outside's blue; bright
    where shelves are dark (a person shares a shelf's orange-brown hue, not its darkness)."""
    hues = {k: hsv(c)[0] for k, c in DRAWN.items()}
    for k, c in DRAWN.items():
        h, s, v = hsv(c)
        assert s >= 150 and v >= 240
        assert grey(c) >= 2 * grey(SHELF_BGR) + 20
        assert not 40 <= h <= 85                                     # goals
        assert hue_gap(h, hsv(OUTSIDE_BGR)[0]) >= 30
        assert hue_gap(h, hsv(GOAL_BGR)[0]) >= 30
        assert all(hue_gap(h, hues[o]) >= 12 for o in KINDS if o != k)
    assert hsv(SHELF_BGR)[2] < 100 and hsv(OUTSIDE_BGR)[2] < 120    # the dark ones


@pytest.mark.parametrize("pads", [False, True])
def test_each_mover_is_drawn_over_its_cell_with_no_marker_over_robots_and_goals_too(pads):
    free = np.ones((6, 10), bool)
    # A person on a robot's cell (they met), a forklift on a goal, a pallet on bare floor.
    scene = Scene(free, {7: (2, 2)}, [(5, 2), (8, 4)], goal_pads=pads,
                  movers=((PERSON, (2, 2)), (FORKLIFT, (5, 2)), (PALLET, (8, 2))))
    bare = dataclasses.replace(scene, movers=())
    model = CameraModel(width=1280, height=960)
    pose = (-3.0, 5.0, -6.0, 0.0)                                  # ~107 px per cell
    image, before = render(scene, pose, model, CELL), render(bare, pose, model, CELL)
    for kind, (x, y) in scene.movers:
        assert tuple(image[pixel_of(model, pose, x + 0.5, y + 0.5)[::-1]]) == DRAWN[kind], kind
        # Uniform inside: no marker's black and white modules.
        px, py = pixel_of(model, pose, x + 0.5, y + 0.5)
        patch = image[py - 15:py + 16, px - 15:px + 16].reshape(-1, 3)
        assert (patch == DRAWN[kind]).all(), kind
    # The forks: two grey tines ahead (north) of the body.
    for side in (-1, 1):
        px, py = pixel_of(model, pose, 5.5 + side * 0.15, 2.2)
        assert tuple(image[py, px]) == FORK_TINE_BGR
    # The robot under the person is hidden; the goal's edge still shows around the forklift with pads.
    assert tuple(before[pixel_of(model, pose, 2.5, 2.5)[::-1]]) != PERSON_BGR
    corner = pixel_of(model, pose, 5.04, 2.04)[::-1]
    assert (tuple(image[corner]) == GOAL_BGR) == pads
    # Nothing else changes: outside the movers' cells the image is the same.
    mask = np.ones(image.shape[:2], bool)
    for _, (x, y) in scene.movers:
        (x0, y0), (x1, y1) = pixel_of(model, pose, x, y), pixel_of(model, pose, x + 1, y + 1)
        mask[y0 - 1:y1 + 2, x0 - 1:x1 + 2] = False
    assert np.array_equal(image[mask], before[mask])


@pytest.mark.parametrize("pads", [False, True])
def test_the_realistic_camera_keeps_each_movers_hue_saturation_and_brightness(pads):
    """Through the lens, the lighting gradient, vignetting, noise and JPEG a mover keeps its hue
    within a few steps and stays bright and saturated, in the dim corner as at the centre."""
    _, free = resolve_map("warehouse-small")
    p = place(free, 8, 1)
    cells = [(int(x), int(y)) for y, x in zip(*np.nonzero(free)) if (int(x), int(y)) not in set(p.starts)]
    picks = [cells[i] for i in np.random.default_rng(0).choice(len(cells), 30, replace=False)]
    movers = tuple((KINDS[i % 3], c) for i, c in enumerate(picks))
    scene = Scene(free, dict(enumerate(p.starts)), p.goals, goal_pads=pads, movers=movers)
    model = CameraModel(**PRESETS["realistic"])
    h, w = free.shape
    pose = (-h / 2, w / 2, -15.0, 0.0)
    frame = encode_frame(render(scene, pose, model, CELL, seed=3), pose, model, 0.0)
    image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_COLOR)
    meta = camera_frame(pose, model, 0.0)
    K = np.array([[meta.fx, 0, meta.cx], [0, meta.fy, meta.cy], [0, 0, 1]])
    dist = np.array([meta.k1, meta.k2, meta.p1, meta.p2, meta.k3])
    image = cv2.undistort(image, K, dist)
    floor_grey = []
    for kind, (x, y) in movers:
        px, py = pixel_of(model, pose, x + 0.5, y + 0.55)            # inside every kind's body
        patch = cv2.cvtColor(image[py - 3:py + 4, px - 3:px + 4], cv2.COLOR_BGR2HSV).reshape(-1, 3)
        h_, s_, v_ = np.median(patch, axis=0)
        assert hue_gap(int(h_), hsv(DRAWN[kind])[0]) <= 3, (kind, (x, y), h_)
        assert s_ >= 0.8 * hsv(DRAWN[kind])[1] and v_ >= 1.5 * hsv(SHELF_BGR)[2], (kind, (x, y), s_, v_)
        floor_grey.append(v_)
    assert min(floor_grey) < 0.85 * max(floor_grey)                  # the lighting did vary over them


def test_only_the_movers_in_the_textures_window_are_drawn(monkeypatch):
    """A close view of the 450 floor with 20,000 movers on it draws the few in view, a few calls each."""
    r = importlib.import_module("sim_world.camera.render")   # the package's `render` is the function

    _, free = resolve_map("warehouse-450")
    cells = [(int(x), int(y)) for y, x in zip(*np.nonzero(free))]
    picks = [cells[i] for i in np.random.default_rng(1).choice(len(cells), 20000, replace=False)]
    scene = Scene(free, movers=tuple((KINDS[i % 3], c) for i, c in enumerate(picks)))
    calls = {"n": 0}
    for name in ("_rect", "_square"):
        real = getattr(r, name)
        monkeypatch.setattr(r, name, lambda *a, _real=real: (calls.__setitem__("n", calls["n"] + 1), _real(*a)))
    real_circle = r.cv2.circle
    monkeypatch.setattr(r.cv2, "circle",
                        lambda *a, **k: (calls.__setitem__("n", calls["n"] + 1), real_circle(*a, **k))[1])
    model = CameraModel(width=640, height=480)
    n, e = cell_centre_ned((200, 200), CELL)
    render(scene, (n, e, -8.0, 0.0), model, CELL)                     # ~16 x 12 cells in view
    near = sum(1 for _, (x, y) in scene.movers if abs(x - 200) <= 12 and abs(y - 200) <= 10)
    assert 0 < near and calls["n"] <= 3 * near
