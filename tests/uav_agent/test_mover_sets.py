"""The sets of cells where movers may be: grown by speed between images, cleared by what an image
shows, and never missing a mover that is really there, however little of the floor each image sees."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from scenarios.maps import random_map
from sim_world.movers import FORKLIFT, PALLET, PERSON, place_movers, step_movers
from uav_agent.planning.mover_sets import MoverSets, grown


def test_a_set_grows_by_the_kinds_speed_round_shelves_not_through_them():
    free = np.ones((5, 7), bool)
    free[0:4, 3] = False                                # a wall with a gap at the bottom row
    sets = MoverSets(free)
    sets.look(0, [(PERSON, (1, 1)), (FORKLIFT, (5, 1)), (PALLET, (6, 4))])
    sets.advance(2)
    person, forklift = sets.sets[PERSON], sets.sets[FORKLIFT]
    assert person[1, 1] and person[3, 1] and not person[4, 2]          # two steps, no more
    assert not person[1, 4], "through the wall"
    assert forklift[4, 5] and forklift[1, 4] and not forklift[4, 2]   # 4 steps: not round the wall's end
    assert sets.sets[PALLET].sum() == 1 and sets.sets[PALLET][4, 6]


def test_a_look_clears_what_it_saw_and_leaves_the_rest_growing():
    free = np.ones((6, 10), bool)
    sets = MoverSets(free)
    sets.look(0, [(PERSON, (1, 1)), (PERSON, (8, 4))])
    left = np.zeros_like(free)
    left[:, :5] = True
    sets.look(3, [(PERSON, (2, 2))], seen=left)         # the left half: one person, now at (2, 2)
    person = sets.sets[PERSON]
    assert person[2, 2] and person[:, :5].sum() == 1
    assert person[4, 8] and person[2, 7] and person[4, 5] and not person[1, 6]   # the right one, unseen: 3 steps
    assert not person[1, 1]


def test_the_forecast_closes_a_cell_from_the_first_tick_a_mover_may_be_there():
    free = np.ones((1, 9), bool)
    sets = MoverSets(free)
    sets.look(4, [(FORKLIFT, (0, 0)), (PERSON, (8, 0))])
    fc = sets.forecast(6)
    assert fc.closed((0, 0), 4) and fc.closed((2, 0), 5) and not fc.closed((3, 0), 5) and fc.closed((4, 0), 6)
    assert fc.closed((7, 0), 5) and not fc.closed((6, 0), 5) and fc.closed((6, 0), 6)
    assert {r.kind for r in fc.reaches} == {FORKLIFT, PERSON}


def test_an_unknown_kind_is_taken_at_the_fastest():
    sets = MoverSets(np.ones((1, 9), bool))
    sets.look(0, [("unknown", (4, 0))])
    sets.advance(1)
    assert sets.sets[FORKLIFT].sum() == 5


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), people=st.integers(1, 4), forklifts=st.integers(0, 3),
       every=st.integers(1, 4), view=st.integers(4, 16))
def test_every_mover_is_always_inside_the_forecast_whatever_each_image_sees(seed, people, forklifts, every, view):
    free = random_map(16, 16, 0.2, seed)
    rng = np.random.default_rng(seed)
    movers = place_movers(free, [PERSON] * people + [FORKLIFT] * forklifts, set(), rng)
    sets = MoverSets(free)
    sets.look(0, [(m.kind, m.cell) for m in movers])
    for tick in range(1, 40):
        sets.advance(tick - 1)
        fc = sets.forecast(tick)
        movers, ways = step_movers(free, movers, set(), rng, tick=tick)
        for way in ways.values():
            assert all(fc.closed(c, tick) for c in way), "a mover passed a cell the forecast left open"
        if tick % every == 0:                          # a window of the floor, wherever it falls
            x0, y0 = rng.integers(0, 16 - view + 1, size=2)
            seen = np.zeros_like(free)
            seen[y0:y0 + view, x0:x0 + view] = True
            sets.look(tick, [(m.kind, m.cell) for m in movers if seen[m.cell[1], m.cell[0]]], seen)


def test_grown_is_breadth_first_over_free_cells():
    free = np.ones((3, 3), bool)
    free[1, 1] = False
    start = np.zeros_like(free)
    start[0, 0] = True
    assert grown(start, free, 2).sum() == 3 + 0 + 2 - 0   # (0,0) (1,0) (2,0) (0,1) (0,2)
