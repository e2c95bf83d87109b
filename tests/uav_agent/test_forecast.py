"""The movers' tracker and forecast (uav_agent/planning/forecast.py), without a world process: which
sighting continues which track, what a miss does, and that the forecast covers every cell the
world's movers (sim_world/movers.py) actually pass, stops at shelves and keeps pallets still."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scenarios.maps import random_map, resolve_map
from sim_world.movers import FORKLIFT, PALLET, PERSON, place_movers, step_movers
from uav_agent.planning.forecast import (
    SPEED,
    UNKNOWN,
    Sighting,
    Track,
    Tracker,
    forecast,
    reach_field,
)


def rows(*lines: str) -> np.ndarray:
    return np.array([[c != "#" for c in line] for line in lines], dtype=bool)


OPEN = np.ones((12, 12), dtype=bool)
# two aisles with a shelf between them: (4, 0) and (4, 2) are 2 apart as the crow flies, 10 on foot
SHELF = rows(
    "..........",
    ".########.",
    "..........",
)


def test_the_world_and_the_uav_agree_on_speeds():
    from sim_world.movers import SPEED as WORLD
    assert dict(SPEED) == dict(WORLD)


def test_reach_field_is_the_walk_around_shelves():
    (x0, y0), dist = reach_field(SHELF, (4, 0), 20)
    assert (x0, y0) == (0, 0)
    assert dist[0, 4] == 0 and dist[0, 9] == 5 and dist[2, 4] == 10 and dist[2, 1] == 7 and dist[1, 4] == -1
    (x0, y0), near = reach_field(SHELF, (4, 0), 3)
    assert (x0, y0) == (1, 0) and near.shape == (3, 7)
    assert near.max() == 3 and (near[2] == -1).all()


def test_a_sighting_continues_the_track_that_could_have_walked_there():
    tr = Tracker(OPEN)
    first = tr.update(0, [(PERSON, (2, 2)), (FORKLIFT, (8, 8))])
    assert first.new == (0, 1) and not first.matched
    # two ticks on: the person one step, the forklift three (it may go 4)
    up = tr.update(2, [(FORKLIFT, (8, 5)), (PERSON, (3, 2))])
    assert dict(up.matched) == {0: (3, 2), 1: (8, 5)} and not up.new
    assert tr.tracks[0].velocity == (0.5, 0.0) and tr.tracks[1].velocity == (0.0, -1.5)
    assert tr.tracks[1].seen == 2 and tr.tracks[1].kind == FORKLIFT


def test_a_sighting_out_of_every_tracks_reach_is_a_new_track():
    tr = Tracker(OPEN)
    tr.update(0, [(PERSON, (2, 2))])
    up = tr.update(1, [(PERSON, (2, 5))])          # 3 cells in one tick: not that person
    assert up.new == (1,) and not up.matched and up.missed == (0,)
    assert set(tr.tracks) == {0, 1}


def test_kinds_do_not_mix_but_an_unknown_kind_matches_and_keeps_the_known_one():
    tr = Tracker(OPEN)
    tr.update(0, [(PERSON, (2, 2))])
    up = tr.update(1, [(FORKLIFT, (2, 3))])
    assert up.new == (1,)
    up = tr.update(2, [(UNKNOWN, (2, 4)), (UNKNOWN, (2, 2))])
    assert dict(up.matched) == {0: (2, 2), 1: (2, 4)}
    assert tr.tracks[0].kind == PERSON and tr.tracks[1].kind == FORKLIFT


def test_a_shelf_is_not_crossed_to_match():
    tr = Tracker(SHELF)
    tr.update(0, [(PERSON, (4, 0))])
    up = tr.update(2, [(PERSON, (4, 2))])           # 2 cells away across the shelf, 10 around it
    assert up.new == (1,) and up.missed == (0,)


def test_the_nearest_to_where_the_velocity_points_wins():
    tr = Tracker(OPEN)
    tr.update(0, [(PERSON, (5, 5))])
    tr.update(1, [(PERSON, (6, 5))])               # heading +x
    up = tr.update(2, [(PERSON, (7, 5)), (PERSON, (5, 5))])
    assert dict(up.matched) == {0: (7, 5)} and len(up.new) == 1


def test_a_miss_keeps_the_track_one_more_image_then_drops_it_and_says_so():
    tr = Tracker(OPEN)
    tr.update(0, [(PERSON, (2, 2)), (PERSON, (9, 9))])
    up = tr.update(1, [(PERSON, (9, 9))])
    assert up.missed == (0,) and 0 in tr.tracks and tr.tracks[0].misses == 1
    # kept as it was: its reach keeps growing from where it was seen
    assert tr.tracks[0].seen == 0 and tr.forecast(3).closed((2, 5), 3)
    up = tr.update(2, [(PERSON, (9, 9))])
    assert up.dropped == (0,) and 0 not in tr.tracks
    assert [(t, k.id) for t, k in tr.dropped] == [(2, 0)]


def test_a_sighting_resets_the_misses():
    tr = Tracker(OPEN)
    tr.update(0, [(PERSON, (2, 2))])
    tr.update(1, [])
    up = tr.update(2, [(PERSON, (2, 3))])
    assert dict(up.matched) == {0: (2, 3)} and tr.tracks[0].misses == 0


def test_a_track_out_of_view_is_kept_and_not_counted_as_missed():
    tr = Tracker(OPEN)
    tr.update(0, [(PERSON, (2, 2))])
    view = np.zeros_like(OPEN)
    view[:, 6:] = True                             # the image showed the right half only
    for tick in (1, 2, 3):
        up = tr.update(tick, [], view)
        assert up.unseen == (0,) and not up.missed and not up.dropped
    assert tr.tracks[0].misses == 0
    # partly in view is not enough to count a miss either
    view[:, 3:] = True
    assert tr.update(4, [], view).unseen == (0,)


def test_images_come_in_order():
    tr = Tracker(OPEN)
    tr.update(5, [])
    with pytest.raises(ValueError):
        tr.update(4, [])


def test_the_forecast_grows_with_time_at_each_kinds_speed():
    tracks = [Track(0, PERSON, (3, 3), 0), Track(1, FORKLIFT, (8, 8), 1)]
    fc = forecast(OPEN, tracks, 6)
    before = fc.mask(0)
    assert before.sum() == 1 and before[3, 3]      # the forklift was not seen yet at tick 0
    for t in range(1, 7):
        m = fc.mask(t)
        assert (m >= before).all() and m.sum() > before.sum()
        ys, xs = np.nonzero(OPEN)
        person = {(int(x), int(y)) for x, y in zip(xs, ys) if abs(x - 3) + abs(y - 3) <= t}
        fork = {(int(x), int(y)) for x, y in zip(xs, ys) if abs(x - 8) + abs(y - 8) <= 2 * (t - 1)}
        assert fc.cells(t) == person | fork
        before = m
    assert fc.closed((3, 6), 3) and not fc.closed((3, 6), 2)


def test_the_forecast_stops_at_shelves():
    fc = forecast(SHELF, [Track(0, PERSON, (4, 0), 0)], 12)
    assert not fc.closed((4, 2), 9) and fc.closed((4, 2), 10)
    assert not fc.mask(12)[1, 1:9].any()           # never on the shelf


def test_a_pallet_stays_where_it_lies():
    fc = forecast(OPEN, [Track(0, PALLET, (4, 4), 2)], 50)
    assert fc.cells(50) == {(4, 4)} and fc.closed((4, 4), 2) and not fc.closed((4, 4), 1)


def test_an_unknown_kind_moves_at_the_fastest_speed():
    fc = forecast(OPEN, [Track(0, "drone on wheels", (5, 5), 0)], 2)
    assert fc.closed((5, 9), 2) and not fc.closed((5, 10), 2)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), density=st.floats(0.0, 0.3), people=st.integers(1, 5),
       forklifts=st.integers(0, 3), pallets=st.integers(0, 2), look=st.integers(1, 5))
def test_the_forecast_covers_every_cell_the_worlds_movers_pass(seed, density, people, forklifts, pallets, look):
    free = random_map(20, 16, density, seed)
    rng = np.random.default_rng(seed)
    kinds = [PERSON] * people + [FORKLIFT] * forklifts + [PALLET] * pallets
    movers = place_movers(free, kinds, set(), rng)
    tracker = Tracker(free)
    for tick in range(30):
        if tick % look == 0:
            up = tracker.update(tick, [(m.kind, m.cell) for m in movers])
            assert not up.new or tick == 0, "a mover seen again was taken for a new one"
            assert not up.missed and not up.dropped
        fc = tracker.forecast(tick + 1)
        movers, ways = step_movers(free, movers, set(), rng)
        for way in ways.values():
            for cell in way:
                assert fc.closed(cell, tick + 1), f"a mover passed {cell} at tick {tick + 1} outside the forecast"
    assert len(tracker.tracks) == len(kinds)


def test_on_a_shipped_warehouse_the_sightings_keep_their_tracks():
    _, free = resolve_map("warehouse-small")
    rng = np.random.default_rng(3)
    movers = place_movers(free, [PERSON, PERSON, FORKLIFT, FORKLIFT, PALLET], set(), rng)
    tracker = Tracker(free)
    ids = None
    for tick in range(40):
        if tick % 2 == 0:
            up = tracker.update(tick, [Sighting(m.kind, m.cell) for m in movers])
            cells = {tracker.tracks[t].cell: tracker.tracks[t].kind for t in tracker.tracks}
            assert cells == {m.cell: m.kind for m in movers}
            ids = ids or set(tracker.tracks)
            assert set(tracker.tracks) == ids and not up.new or tick == 0
        movers, _ = step_movers(free, movers, set(), rng)


def test_a_tracker_reuses_its_fields_and_forecasts_what_a_fresh_walk_does():
    _, free = resolve_map("warehouse-small")
    rng = np.random.default_rng(11)
    movers = place_movers(free, [PERSON, PERSON, FORKLIFT, PALLET], set(), rng)
    tracker = Tracker(free)
    for tick in range(24):
        if tick % 5 == 0:
            tracker.update(tick, [(m.kind, m.cell) for m in movers])
        for until in (tick + 1, tick + 3):
            cached = tracker.forecast(until)
            fresh = forecast(free, tracker.tracks.values(), until)
            assert np.array_equal(cached.flat, fresh.flat) and np.array_equal(cached.first, fresh.first)
            for a, b in zip(cached.reaches, fresh.reaches):
                assert a.corner == b.corner and np.array_equal(a.dist, b.dist)
        movers, _ = step_movers(free, movers, set(), rng)
    assert len(tracker._fields) == len(tracker.tracks)
