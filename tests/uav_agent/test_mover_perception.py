"""People, forklifts and pallets perceived from real images: each on its cell with its kind, and
the rest of the world model as it is without them.

Every image is rendered by sim_world.camera (the ideal and the realistic camera: lens, lighting,
vignetting, noise, JPEG) and read through OpenCV by the UAV's own pipeline, registered by the
landmarks where the view resolves them. A model with movers is compared with the model of the
same images without them: the same free cells, robots, goals (but those a mover stands on and
hides), unidentified markers and unsure cells.
"""
from __future__ import annotations

import dataclasses
import math
from functools import lru_cache

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol.messages import CameraFrame
from scenarios.landmarks import place_landmarks
from scenarios.maps import place, resolve_map
from sim_world import movers as world_movers
from sim_world.camera import PRESETS, CameraModel, Scene, cell_centre_ned, encode_frame, render
from sim_world.camera.render import FORKLIFT_BGR, PALLET_BGR, PERSON_BGR, SHELF_BGR
from sim_world.config import DRONE_CAMERA
from uav_agent.perception import Fusion, Landmarks, perceive
from uav_agent.perception.fusion import prepare
from uav_agent.perception.goals import GREEN_HUE
from uav_agent.perception.movers import (FORKLIFT, HUES, KINDS, PALLET, PERSON, MoverSighting, mover_pixels,
                                         movers_from)
from uav_agent.perception.view import to_floor
from uav_agent.survey import survey_poses

CELL = 1.0
NEIGHBOURS = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if (dx, dy) != (0, 0)]


def landmarks_of(scene: Scene) -> Landmarks | None:
    """The scene's landmarks as the UAV knows them (WorldInfo)."""
    if scene.landmarks is None:
        return None
    by_id: dict[int, list] = {}
    for lid, e, n in scene.landmarks.landmarks:
        by_id.setdefault(lid, []).append((e, n))
    return Landmarks(scene.landmarks.family, scene.landmarks.size_m, {k: np.array(v) for k, v in by_id.items()})


@lru_cache(maxsize=8)
def floor(spec: str, robots: int, seed: int, pads: bool, marks: bool = True) -> Scene:
    _, free = resolve_map(spec, 0)
    p = place(free, robots, seed)
    return Scene(free, {(i * 37 + 3) % 1000: c for i, c in enumerate(p.starts)}, p.goals,
                 place_landmarks(free, CELL) if marks else None, goal_pads=pads)


def crowded(scene: Scene, seed: int, extra: int = 0, on_goals: int = 2) -> Scene:
    """`scene` with movers of every kind in the hard places: beside each robot and each goal, beside
    each other (two forklifts side by side, a person by a forklift), on `on_goals` goals, and `extra`
    more anywhere on the floor; never on a robot."""
    rng = np.random.default_rng(seed)
    h, w = scene.free.shape
    robots, goals = set(scene.robots.values()), list(scene.goals)
    taken = robots | set(goals)
    chosen: dict[tuple[int, int], str] = {}

    def free(c) -> bool:
        return 0 <= c[0] < w and 0 <= c[1] < h and bool(scene.free[c[1], c[0]]) and c not in taken and c not in chosen

    def beside(cell):
        options = [(cell[0] + dx, cell[1] + dy) for dx, dy in NEIGHBOURS]
        options = [c for c in options if free(c)]
        return options[int(rng.integers(len(options)))] if options else None

    for i, anchor in enumerate(sorted(robots) + goals):
        c = beside(anchor)
        if c is not None:
            chosen[c] = KINDS[i % 3]
    cells = [(int(x), int(y)) for y, x in zip(*np.nonzero(scene.free))]
    for pair in ((FORKLIFT, FORKLIFT), (PERSON, FORKLIFT), (PALLET, PERSON)):
        for _ in range(50):
            a = cells[int(rng.integers(len(cells)))]
            b = (a[0] + 1, a[1])
            if free(a) and free(b):
                chosen[a], chosen[b] = pair
                break
    for i, g in enumerate(goals[:on_goals]):
        chosen[g] = KINDS[i % 3]
    spare = [c for c in cells if free(c)]
    for i, j in enumerate(rng.choice(len(spare), size=min(extra, len(spare)), replace=False)):
        chosen[spare[j]] = KINDS[i % 3]
    return dataclasses.replace(scene, movers=tuple((k, c) for c, k in sorted(chosen.items())))


def shot(scene: Scene, model: CameraModel, pose, seq: int = 0, error_m: float = 0.0, yaw_err_deg: float = 0.0,
         image: np.ndarray | None = None) -> CameraFrame:
    """The frame the camera takes from the true `pose`, published with an estimate `error_m` off."""
    image = render(scene, pose, model, CELL, seed=seq) if image is None else image
    n, e, d, *rest = pose
    yaw = rest[0] if rest else 0.0
    angle = 0.7 + seq
    est = (n + error_m * math.cos(angle), e + error_m * math.sin(angle), d, yaw + math.radians(yaw_err_deg))
    frame = encode_frame(image, est, model, float(seq), seq=seq)
    return dataclasses.replace(frame, pose_sigma_m=error_m, yaw_sigma_deg=yaw_err_deg) if error_m else frame


def survey(scene: Scene, model: CameraModel, error: bool) -> list[CameraFrame]:
    h, w = scene.free.shape
    err = (model.pose_sigma_m, model.yaw_sigma_deg) if error else (0.0, 0.0)
    return [shot(scene, model, (n, e, -alt, 0.0), i, *err)
            for i, (n, e, alt) in enumerate(survey_poses(w, h, CELL, model, 20.0))]


def assert_movers_change_nothing_else(bare, crowd, scene: Scene, only_seen: bool = False) -> None:
    """`crowd` (the model with the scene's movers) finds every mover the images show whole on its
    cell with its kind and nothing else, and says what `bare` (without them) says of the rest."""
    truth = {(k, c) for k, c in scene.movers if not only_seen or crowd.seen[c[1], c[0]]}
    got = {(m.kind, m.cell) for m in crowd.movers}
    assert got == truth, f"missed {sorted(truth - got)}, false {sorted(got - truth)}"
    hidden = {c for _, c in scene.movers} & set(scene.goals)
    assert set(crowd.goals) ^ set(bare.goals) <= hidden
    assert np.array_equal(crowd.free, bare.free), f"{int((crowd.free != bare.free).sum())} cells changed"
    assert np.array_equal(crowd.seen, bare.seen)
    assert crowd.robots == bare.robots
    assert crowd.unidentified == bare.unidentified
    assert crowd.unsure == bare.unsure
    for _, (x, y) in scene.movers:
        if crowd.seen[y, x]:
            assert crowd.free[y, x] and (x, y) not in crowd.unsure


# --- the floor's contract ----------------------------------------------------------------

def test_the_worlds_mover_colours_are_the_hues_perception_reads_and_bright_as_floor():
    """The world draws each kind in a hue of its own range (none in the goals' green) and brighter
    than twice a shelf's grey, so the occupancy split reads a mover's cell as floor."""
    assert (world_movers.PERSON, world_movers.FORKLIFT, world_movers.PALLET) == (PERSON, FORKLIFT, PALLET)
    drawn = {PERSON: PERSON_BGR, FORKLIFT: FORKLIFT_BGR, PALLET: PALLET_BGR}
    shelf_grey = int(cv2.cvtColor(np.uint8([[SHELF_BGR]]), cv2.COLOR_BGR2GRAY)[0, 0])
    for kind, bgr in drawn.items():
        h, s, v = (int(x) for x in cv2.cvtColor(np.uint8([[bgr]]), cv2.COLOR_BGR2HSV)[0, 0])
        assert [k for k in KINDS if any(lo + 3 <= h <= hi - 3 for lo, hi in HUES[k])] == [kind], (kind, h)
        assert not GREEN_HUE[0] <= h <= GREEN_HUE[1]
        assert s >= 150 and v >= 240
        assert cv2.cvtColor(np.uint8([[bgr]]), cv2.COLOR_BGR2GRAY)[0, 0] > 2 * shelf_grey


# --- the small floor: one survey image, the ideal and the realistic camera -----------------

@pytest.mark.parametrize("preset", ["ideal", "realistic"])
@pytest.mark.parametrize("pads", [False, True])
def test_movers_on_the_small_floor_are_found_and_leave_the_rest_of_the_model_as_it_was(preset, pads):
    model = CameraModel(**PRESETS[preset])
    bare = floor("warehouse-small", 8, 3, pads)
    scene = crowded(bare, seed=3, extra=12)
    kinds = {k for k, _ in scene.movers}
    assert kinds == set(KINDS) and len(scene.movers) >= 30
    h, w = scene.free.shape
    marks = landmarks_of(scene)
    realistic = preset == "realistic"            # its pose estimate is off, the landmarks put it right
    crowd = perceive(survey(scene, model, realistic), w, h, CELL, set(scene.robots), marks)
    plain = perceive(survey(bare, model, realistic), w, h, CELL, set(scene.robots), marks)
    assert plain.robots == bare.robots and sorted(plain.goals) == sorted(bare.goals) and np.array_equal(
        plain.free, bare.free)
    assert_movers_change_nothing_else(plain, crowd, scene)
    assert [w for w in crowd.warnings if "marker" in w] == [w for w in plain.warnings if "marker" in w]


@pytest.mark.parametrize("preset", ["ideal", "realistic"])
def test_each_view_reads_a_movers_cell_as_floor_by_itself(preset):
    """Before the fusion forces them free: the occupancy split of one image already reads every
    mover's cell as floor, and no mover's cell as a marker."""
    model = CameraModel(**PRESETS[preset])
    scene = crowded(floor("warehouse-small", 8, 3, True), seed=4, extra=12)
    h, w = scene.free.shape
    frame = survey(scene, model, False)[0]
    reading = Fusion(w, h, CELL, set(scene.robots), landmarks_of(scene)).measure(frame)
    cells = reading.cells
    for _, (x, y) in scene.movers:
        assert cells.free[y - cells.y0, x - cells.x0], (x, y)
        assert not cells.marker_like[y - cells.y0, x - cells.x0], (x, y)


@given(data=st.data())
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_random_movers_seen_turned_and_from_any_height_are_found_exactly(data):
    bare = floor("warehouse-small", 8, 1, data.draw(st.booleans()), marks=False)
    h, w = bare.free.shape
    cells = [(int(x), int(y)) for y, x in zip(*np.nonzero(bare.free)) if (int(x), int(y)) not in bare.robots.values()]
    picks = data.draw(st.lists(st.tuples(st.sampled_from(KINDS), st.sampled_from(cells)), min_size=1, max_size=40,
                               unique_by=lambda m: m[1]))
    scene = dataclasses.replace(bare, movers=tuple(picks))
    yaw = data.draw(st.sampled_from([0.0, 0.5, -2.0]))
    alt = data.draw(st.sampled_from([14.0, 18.0, 30.0]))             # from 46 down to 21 px per cell
    model = CameraModel(width=1280, height=960)
    pose = (-h / 2, w / 2, -alt, yaw)
    crowd = perceive([shot(scene, model, pose)], w, h, CELL, set(scene.robots))
    plain = perceive([shot(bare, model, pose)], w, h, CELL, set(scene.robots))
    assert_movers_change_nothing_else(plain, crowd, scene, only_seen=True)


def test_a_mover_on_the_open_floors_edge_beside_the_outside_is_found():
    free = np.ones((9, 12), bool)
    bare = Scene(free, {5: (4, 4), 77: (0, 4)}, [(6, 4), (11, 8)])
    scene = dataclasses.replace(bare, movers=((PALLET, (0, 0)), (PERSON, (11, 0)), (FORKLIFT, (5, 8)),
                                              (PALLET, (11, 7)), (PERSON, (0, 5)), (FORKLIFT, (6, 0))))
    model = CameraModel(**PRESETS["realistic"])
    h, w = free.shape
    pose = (-h / 2, w / 2, -12.0, 0.2)      # the outside all around the floor, the pose published exact
    crowd = perceive([shot(scene, model, pose)], w, h, CELL, set(scene.robots))
    plain = perceive([shot(bare, model, pose)], w, h, CELL, set(scene.robots))
    assert plain.unseen == 0 and plain.robots == bare.robots
    assert_movers_change_nothing_else(plain, crowd, scene)


def test_movers_are_found_under_any_exposure():
    scene = crowded(floor("warehouse-small", 8, 2, True), seed=2, extra=10)
    h, w = scene.free.shape
    model = CameraModel()
    pose = (-h / 2, w / 2, -14.0, 0.0)
    image = render(scene, pose, model, CELL)
    truth = {(k, c) for k, c in scene.movers}
    for gain in (0.45, 1.0, 1.15):
        frame = shot(scene, model, pose, image=cv2.convertScaleAbs(image, alpha=gain))
        fusion = Fusion(w, h, CELL, set(scene.robots))
        fusion.add(frame)
        assert {(m.kind, m.cell) for m in fusion.last_movers} == truth, gain


def test_a_mover_the_image_edge_cuts_is_left_to_a_frame_that_sees_it_whole():
    free = np.ones((12, 30), bool)
    scene = Scene(free, movers=((PALLET, (3, 5)), (PERSON, (4, 5)), (FORKLIFT, (3, 7))))
    model = CameraModel(width=1280, height=960)             # fx 640: at 10 m, 64 px per cell
    alt = 10.0
    # The image's left edge runs through the middle of column 3: its movers show half.
    east = 3.5 + (model.cx + 0.5) * alt / model.fx
    pose = (-6.0, east, -alt, 0.0)
    frame = shot(scene, model, pose)
    view = prepare(frame, None, CELL)
    assert abs(to_floor([[-0.5, model.cy]], view.H_inv)[0][0] - 3.5) < 0.01     # the first pixel's left edge
    assert movers_from(mover_pixels(view.image, view.valid), view, (30, 12)) == [MoverSighting(PERSON, (4, 5))]
    whole = shot(scene, model, (-6.0, 8.0, -alt, 0.0), seq=1)
    wm = perceive([frame, whole], 30, 12, CELL)
    assert {(m.kind, m.cell) for m in wm.movers} == set(scene.movers)


# --- the fusion: the latest look at each cell, and what a mover's cell is -------------------

def test_the_model_keeps_each_cells_latest_look_and_the_last_frame_its_own_movers():
    free = np.ones((10, 40), bool)
    model = CameraModel(width=1280, height=960)
    first = Scene(free, movers=((PERSON, (5, 5)), (FORKLIFT, (30, 4))))
    later = Scene(free, movers=((PERSON, (6, 5)), (FORKLIFT, (30, 4))))   # the person walked on
    left, right = (-5.0, 9.0, -12.0, 0.0), (-5.0, 30.0, -12.0, 0.0)       # 24 cells wide each, overlapping
    fusion = Fusion(40, 10, CELL)
    fusion.add(shot(first, model, left, 0))
    fusion.add(shot(first, model, right, 1))
    assert fusion.last_movers == [MoverSighting(FORKLIFT, (30, 4))]
    assert fusion.model().movers == [MoverSighting(PERSON, (5, 5)), MoverSighting(FORKLIFT, (30, 4))]
    fusion.add(shot(later, model, left, 2))
    assert fusion.last_movers == [MoverSighting(PERSON, (6, 5))]
    wm = fusion.model()
    assert wm.movers == [MoverSighting(PERSON, (6, 5)), MoverSighting(FORKLIFT, (30, 4))]
    assert wm.unseen == 0 and wm.free.all()
    fusion.add(shot(Scene(free), model, right, 3))                      # the forklift drove off
    assert fusion.last_movers == [] and fusion.model().movers == [MoverSighting(PERSON, (6, 5))]


def test_a_movers_cell_is_floor_and_no_marker_whatever_the_votes_say():
    free = np.ones((10, 14), bool)
    scene = Scene(free, {9: (2, 2)}, [(10, 6)], movers=((FORKLIFT, (7, 5)),))
    model = CameraModel(width=1280, height=960)
    fusion = Fusion(14, 10, CELL, {9})
    reading = fusion.measure(shot(scene, model, (-5.0, 7.0, -14.0, 0.0)))
    assert reading.movers == [MoverSighting(FORKLIFT, (7, 5))]
    cells = reading.cells
    # Votes that took the forklift's cell for a shelf and for a marker's contrast (darker forks would).
    cells.free[5 - cells.y0, 7 - cells.x0] = False
    cells.confidence[5 - cells.y0, 7 - cells.x0] = 1.0
    cells.marker_like[5 - cells.y0, 7 - cells.x0] = True
    fusion.merge(reading)
    wm = fusion.model()
    assert wm.free.all() and wm.unsure == [] and wm.unidentified == []
    assert wm.robots == {9: (2, 2)} and wm.goals == [(10, 6)]
    assert wm.movers == [MoverSighting(FORKLIFT, (7, 5))]


# --- the 450 floor, from far ----------------------------------------------------------------

def far_view(preset: str, pads: bool, camera: dict, ppc: float) -> tuple:
    """A view of the 450 floor at `ppc` pixels per cell, its pose published exact (the landmarks are
    too small to read from so high), with a crowd of movers in it; the models with and without."""
    model = CameraModel(**{**camera, **PRESETS[preset]})
    bare = floor("warehouse-450", 50, 5, pads)
    scene = crowded(bare, seed=5, extra=3000, on_goals=50)      # a third of them people, who hide a goal
    alt = model.fx * CELL / ppc
    pose = (-225.0, 225.0, -alt, 0.0)
    crowd = perceive([shot(scene, model, pose)], 450, 450, CELL, set(scene.robots))
    plain = perceive([shot(bare, model, pose)], 450, 450, CELL, set(scene.robots))
    return scene, crowd, plain


@pytest.mark.parametrize("preset", ["ideal", "realistic"])
def test_movers_on_the_450_floor_from_far_at_under_7_px_per_cell(preset):
    scene, crowd, plain = far_view(preset, True, {"width": 1280, "height": 960}, 6.6)
    seen = [c for _, c in scene.movers if crowd.seen[c[1], c[0]]]
    assert len(seen) >= 300
    assert_movers_change_nothing_else(plain, crowd, scene, only_seen=True)


def test_the_haze_a_blurred_mover_casts_over_a_shelf_beside_it_is_no_mover():
    """Far beyond the survey's blur (2 px at 6.6 px per cell), a forklift's or a person's colour spills
    over the shelf beside it up to that cell's centre; the view reads the shelf as a shelf, and the
    model sees no mover there (which would make it floor)."""
    model = CameraModel(**{**PRESETS["realistic"], "width": 1280, "height": 960, "blur_sigma": 2.0})
    bare = floor("warehouse-450", 50, 5, True)
    scene = crowded(bare, seed=5, extra=6000, on_goals=6)
    pose = (-200.5, 300.5, -model.fx / 6.6, 0.0)
    crowd = perceive([shot(scene, model, pose)], 450, 450, CELL, set(scene.robots))
    assert len(crowd.movers) > 300
    assert all(scene.free[m.cell[1], m.cell[0]] for m in crowd.movers)


@pytest.mark.slow
@pytest.mark.parametrize("preset, pads", [("ideal", False), ("realistic", True)])
def test_the_whole_450_floor_in_one_12_mp_image_shows_every_mover(preset, pads):
    scene, crowd, plain = far_view(preset, pads, DRONE_CAMERA, 3000 / 454)
    assert crowd.unseen == 0 and len(scene.movers) > 3000
    assert_movers_change_nothing_else(plain, crowd, scene)


def test_movers_in_a_12_mp_image_from_the_450_survey_altitude_registered_by_the_landmarks():
    model = CameraModel(**{**DRONE_CAMERA, **PRESETS["realistic"]})
    bare = floor("warehouse-450", 50, 5, True)
    scene = crowded(bare, seed=6, extra=4000, on_goals=50)
    alt = max(p[2] for p in survey_poses(450, 450, CELL, model, 20.0))
    n, e = cell_centre_ned((225, 225), CELL)
    marks = landmarks_of(scene)
    frames = [shot(s, model, (n, e, -alt, 0.0), error_m=model.pose_sigma_m, yaw_err_deg=model.yaw_sigma_deg)
              for s in (scene, bare)]
    crowd, plain = (perceive([f], 450, 450, CELL, set(scene.robots), marks) for f in frames)
    assert all(r.source == "landmarks" for r in crowd.frames)
    assert sum(crowd.seen[c[1], c[0]] for _, c in scene.movers) >= 200
    assert_movers_change_nothing_else(plain, crowd, scene, only_seen=True)
