"""Closer looks cover every doubtful cell: the survey's gaps (a body-fixed camera leaning as
the vehicle brakes), unreadable markers and unsure cells, with a capped number of hovers.

The geometry tests are pure; the mission test renders real images through
sim_world.camera and reads them through OpenCV, as bench perception does.
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from uav_agent.perception.relook import MAX_HOVERS, closer_look, hover_points, plan_round
from uav_robots.bench.perception import bench_scene, score, simulate
from sim_world.camera import PRESETS, CameraModel

CAMERA = SimpleNamespace(width=1280, height=960, fx=640.0, fy=640.0)


def _inside_tilted(cell, hover, alt, tilt_rad, camera=CAMERA) -> bool:
    """Cell wholly inside the image of a camera at `hover` leaning `tilt_rad` in the worst direction."""
    n, e = hover
    swing = alt * math.tan(tilt_rad)
    half_e = camera.width / camera.fx * alt / 2 - swing
    half_n = camera.height / camera.fy * alt / 2 - swing
    x, y = cell
    return abs(x + 0.5 - e) + 0.5 <= half_e and abs(-(y + 0.5) - n) + 0.5 <= half_n


def test_hover_points_keep_cells_in_view_through_the_stated_tilt():
    cells = [(x, y) for x in range(0, 120, 3) for y in range(0, 90, 4)]
    tilt = math.radians(10.0)
    points = hover_points(cells, 1.0, 30.0, 1280, 960, 640.0, 640.0, tilt_rad=tilt)
    level = hover_points(cells, 1.0, 30.0, 1280, 960, 640.0, 640.0)
    assert len(points) > len(level)          # the swing costs footprint
    for c in cells:
        assert any(_inside_tilted(c, p, 30.0, tilt) for p in points), c


def test_a_closer_look_rises_rather_than_exceed_its_hovers_and_never_drops_a_cell_it_can_avoid():
    cells = [(x, y) for x in range(0, 300, 5) for y in range(0, 300, 5)]
    alt, points = closer_look(cells, 1.0, 10.0, 60.0, CAMERA)
    assert alt > 10.0 and len(points) <= MAX_HOVERS
    for c in cells:
        assert any(_inside_tilted(c, p, alt, 0.0) for p in points), c
    # Capped at the survey's height: the nearest hovers now, the rest in a later round.
    alt, points = closer_look(cells, 1.0, 10.0, 12.0, CAMERA, max_hovers=5)
    assert alt == 12.0 and len(points) == 5


def test_unseen_cells_are_seen_from_the_survey_height_unreadable_markers_from_lower():
    h, w = 100, 100
    seen = np.ones((h, w), bool)
    seen[40:60, :] = False                   # a strip between two leaning images
    model = SimpleNamespace(seen=seen, unsure=[], unidentified=[(5, 5)], robots={1: (5, 5)}, goals=[(9, 9)])
    targets, hovers = plan_round(model, {1}, True, 1, 40.0, 1.0, CAMERA)
    assert (5, 5) in targets and (0, 40) in targets and len(targets) == 1 + 20 * w
    assert {alt for _, _, alt in hovers} == {20.0, 40.0}
    low = [(n, e) for n, e, alt in hovers if alt == 20.0]
    assert len(low) == 1 and _inside_tilted((5, 5), low[0], 20.0, 0.0)
    for x in range(w):
        for y in range(40, 60):
            assert any(_inside_tilted((x, y), (n, e), alt, 0.0) for n, e, alt in hovers if alt == 40.0)
    done = SimpleNamespace(seen=np.ones((h, w), bool), unsure=[], unidentified=[], robots={1: (5, 5)}, goals=[(9, 9)])
    assert plan_round(done, {1}, True, 1, 40.0, 1.0, CAMERA) == ([], [])


def test_a_survey_taken_leaning_20_degrees_is_completed_by_level_closer_looks():
    """The 450 mission's failure in small: every survey image leans by the vehicle's tilt
    limit, footprints swing by a third of the altitude, cells between them go unseen."""
    model = CameraModel(**PRESETS["realistic"])
    scene = bench_scene("random:width=40,height=40,density=0.2", 6)
    wm, images, _ = simulate(scene, model, survey_tilt_deg=20.0)
    assert wm.unseen == 0 and wm.unsure == []
    assert score(wm, scene) == (0, 0, 0)
    assert images > 1                        # the survey's one image left ~400 cells unseen: looks filled them


def test_a_closer_look_slides_to_keep_two_landmarks_in_view_and_its_cells_inside():
    # At 8 m the view is 16 x 12 m; centred on the cell it holds no landmark; two lie 10-12 m east.
    anchors = np.array([[12.0, -60.5], [13.0, -57.0], [40.0, -10.0]])     # (east, north)
    cell = (1, 59)
    (n0, e0), = hover_points([cell], 1.0, 8.0, 1280, 960, 640.0, 640.0)
    (n, e), = hover_points([cell], 1.0, 8.0, 1280, 960, 640.0, 640.0, anchors_en=anchors)
    assert (n0, e0) == (-59.5, 1.5) and e > e0
    assert _inside_tilted(cell, (n, e), 8.0 * 0.8, 0.0)              # whole inside, within the margin
    view_e, view_n = 8.0 - 1.0, 6.0 - 1.0
    assert sum(abs(ae - e) <= view_e and abs(an - n) <= view_n for ae, an in anchors) == 2


def test_while_a_robot_is_missing_lone_shelf_cells_get_a_closer_look():
    free = np.ones((10, 10), bool)
    free[4, 4] = False                        # alone in the floor: a blurred robot reads like this
    free[0:3, 7:10] = False                   # a shelf block ...
    free[3, 8] = False                        # ... with a one-cell bump: a robot in the aisle beside it
    model = SimpleNamespace(seen=np.ones((10, 10), bool), free=free, unsure=[], unidentified=[],
                            robots={1: (1, 1)}, goals=[(2, 2), (3, 3)])
    targets, _ = plan_round(model, {1, 2}, True, 1, 20.0, 1.0, CAMERA)
    assert targets == [(4, 4), (8, 3)]
    assert plan_round(model, {1}, True, 1, 20.0, 1.0, CAMERA) == ([], [])


@pytest.fixture
def mission_context():
    """MissionContexts on in-memory sessions: the phases' state, nothing flown yet; closed after the test."""
    from protocol.transport import MemoryBus, MemoryTransport
    from uav_agent.mission import MissionConfig, MissionContext
    from uav_agent.progress import Progress

    made = []

    def make(tick: int = 0):
        ctx = MissionContext(MissionConfig(fleet="t"), MemoryTransport(MemoryBus()), Progress(enabled=False))
        ctx.tick = tick
        made.append(ctx)
        return ctx
    yield make
    for ctx in made:
        ctx.fleet.close()
        ctx.transport.close()


@pytest.fixture
def looking(monkeypatch, mission_context):
    """A context with an in-memory vehicle over a 40x40 floor surveyed from 30 m, whose image
    tours are only recorded in `toured`: enough for the looking phases (looks.see, verify.run)."""
    from sim_world.camera import camera_frame
    from uav_agent.mission import looks

    toured: list = []
    monkeypatch.setattr(looks, "tour", lambda ctx, hovers, fusion: toured.append(hovers))

    def make(tick: int = 0):
        ctx = mission_context(tick)
        ctx.flight = SimpleNamespace(position_ned=lambda: (-20.0, 20.0, -30.0), goto=lambda *a: None)
        ctx.info = SimpleNamespace(cell_size_m=1.0)
        v = ctx.vantage
        v.alt, v.poses, v.hover = 30.0, [(0.0, 0.0, 30.0)], (-20.0, 20.0, 30.0)
        v.calibration = camera_frame((0.0, 0.0, -30.0), CameraModel(width=1280, height=960, fx=640.0, fy=640.0), 0.0)
        return ctx, toured
    return make


def test_a_closer_look_is_an_event_of_the_mission_naming_what_was_in_doubt(looking):
    """looks.see with an in-memory fusion and vehicle: the closer look it flies goes into the
    report's events (kind closer-look), naming the unread marker and the robot not yet seen."""
    from uav_agent.perception.fusion import WorldModel

    free = np.ones((40, 40), bool)
    doubt = WorldModel(free=free, robots={1: (3, 3)}, goals=[(5, 5), (6, 6)], seen=free, unseen=0,
                       unidentified=[(20, 21)])
    clear = WorldModel(free=free, robots={1: (3, 3), 2: (20, 21)}, goals=[(5, 5), (6, 6)], seen=free, unseen=0)
    models = iter([doubt, clear])
    from uav_agent.mission import looks

    m, toured = looking()
    fusion = SimpleNamespace(known_ids={1, 2}, model=lambda: next(models))
    assert looks.see(m, fusion) is clear and len(toured) == 1
    (e,) = m.events.as_dicts()
    assert e["kind"] == "closer-look" and e["robots"] == [2]
    assert "1 unreadable marker(s) at [(20, 21)]" in e["what"] and "round 1" in e["action"]


def test_the_shutter_waits_for_an_attitude_sent_after_the_arrival(mission_context):
    """The attitude read with the arrival may be the cruise's (level): the shutter waits for a
    later sample, which shows the braking, and for that tilt to decay."""
    from uav_agent.mission import looks

    samples = iter([(0.0, 0.0, 0.0, 100), (0.0, 0.0, 0.0, 100), (0.35, 0.0, 0.0, 140), (0.05, 0.0, 0.0, 180),
                    (0.001, 0.0, 0.0, 220)])
    read = []

    def sample():
        s = next(samples)
        read.append(s)
        return s

    m = mission_context()
    m.flight = SimpleNamespace(attitude_sample=sample)
    looks.hold_level(m)
    assert read[-1][3] == 220


def test_an_image_shot_leaning_is_taken_again_level_and_the_report_says_why(mission_context):
    """looks.retake with an in-memory vehicle: the survey's image set aside for its lean
    (Shots.missed) is taken again over its pose, and the report's events name why."""
    from uav_agent.mission import looks

    flown, added = [], []
    m = mission_context()
    m.flight = SimpleNamespace(goto=lambda *a: flown.append(a), attitude_sample=lambda: (0.0, 0.0, 0.0, 0))
    m.vantage.hover = (-20.0, 20.0, 30.0)
    m.capture = lambda: "level frame"
    shots = SimpleNamespace(missed=[(-10.0, 5.0, 30.0)], why_missed=["taken leaning 20.0 degrees"])
    looks.retake(m, shots, SimpleNamespace(add=added.append))
    assert flown == [(-10.0, 5.0, 30.0), (-20.0, 20.0, 30.0)] and added == ["level frame"]
    assert m.uav["retaken_images"] == 1
    (e,) = m.events.as_dicts()
    assert e["kind"] == "retake" and "taken leaning 20.0 degrees at (-10.0, 5.0, 30.0)" in e["what"]


def test_a_robot_that_raised_done_but_was_seen_nowhere_gets_a_closer_look_at_its_goal_before_it_is_doubted(
        looking, monkeypatch):
    """verify.run with an in-memory fleet, vehicle and fusion: the verification's look sees
    robot 1 on its goal and robot 2 nowhere; a closer look over robot 2's goal (half the survey's
    height) sees it there, so both are verified and the report names the closer look. A robot the
    look sees somewhere else is not looked for again: its Done is contradicted."""
    from uav_agent.mission import looks, verify
    from uav_agent.mission.state import PlanState
    from uav_agent.perception.fusion import WorldModel

    free = np.ones((40, 40), bool)
    goals = {1: (5, 5), 2: (20, 21), 3: (30, 30)}
    m, toured = looking(tick=249)
    m.plans.ids, m.plans.goal_of = [1, 2, 3], goals
    m.plans.now = PlanState("p", 0, {r: [g] for r, g in goals.items()}, goals)
    m.fleet.done.update({1: None, 2: None, 3: None})
    m.done_for = lambda r, plan: True
    # 2 seen nowhere, 3 off its goal
    monkeypatch.setattr(looks, "look", lambda ctx, cells, back=True, expected=None: {1: goals[1], 3: (29, 30)})
    closer = WorldModel(free=free, robots={2: goals[2]}, goals=[goals[2]], seen=free, unseen=0)
    m.fusion = lambda known=None: SimpleNamespace(known_ids=known, model=lambda: closer)
    verify.run(m)
    assert m.arrivals.verified == {1: True, 2: True, 3: False}
    (hovers,) = toured
    assert hovers and all(alt == 15.0 for _, _, alt in hovers)
    kinds = [(e["kind"], e["robots"]) for e in m.events.as_dicts()]
    assert kinds == [("closer-look", [2]), ("done-contradicted", [3])]


def test_a_look_for_some_robots_flies_no_closer_look_for_the_others(looking):
    """looks.see with `expected`: the verification's look over the goals still unconfirmed
    is for those robots; a robot confirmed elsewhere is not in its images, and taking it for
    missing sent the vehicle over every lone obstacle of a random floor (three rounds, 24 s)."""
    from uav_agent.perception.fusion import WorldModel

    free = np.ones((40, 40), bool)
    free[10, 10] = free[30, 5] = False               # lone obstacles: a blurred marker could look like one
    seen = WorldModel(free=free, robots={1: (3, 3)}, goals=[(3, 3)], seen=np.ones((40, 40), bool), unseen=0)
    from uav_agent.mission import looks

    for expected, rounds in (({1}, 0), (None, 3)):
        m, toured = looking()
        toured.clear()
        fusion = SimpleNamespace(known_ids={1, 2}, model=lambda: seen)
        assert looks.see(m, fusion, for_map=False, expected=expected) is seen
        assert len(toured) == rounds
