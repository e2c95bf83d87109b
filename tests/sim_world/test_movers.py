"""The world's movers alone (no process, no network): where they may go, how fast, and what counts
as a robot touching one."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.errors import MapError
from scenarios.maps import random_map, resolve_map
from sim_world.movers import (
    FORKLIFT,
    PALLET,
    PERSON,
    SPEED,
    Contact,
    Mover,
    MoverRules,
    contacts,
    near_misses,
    place_movers,
    step_movers,
)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), density=st.floats(0.0, 0.3), people=st.integers(1, 6),
       forklifts=st.integers(0, 4), pallets=st.integers(0, 2))
def test_movers_keep_to_free_cells_their_speed_and_out_of_what_stands_there(seed, density, people, forklifts, pallets):
    free = random_map(16, 16, density, seed)
    rng = np.random.default_rng(seed)
    kinds = [PERSON] * people + [FORKLIFT] * forklifts + [PALLET] * pallets
    cells = [(int(x), int(y)) for y, x in zip(*np.nonzero(free))]
    robots = {cells[i] for i in rng.choice(len(cells), size=min(5, len(cells) // 4), replace=False)}
    movers = place_movers(free, kinds, robots, rng)
    start = {m.id: m.cell for m in movers}
    for _ in range(40):
        movers, ways = step_movers(free, movers, robots, rng)
        assert len({m.cell for m in movers}) == len(movers), "two movers on one cell"
        for m in movers:
            way = ways[m.id]
            assert all(free[y, x] for x, y in way) and m.cell == way[-1]
            assert not set(way[1:]) & robots, "a mover stepped into a robot"
            assert len(way) - 1 <= SPEED[m.kind]
            assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) == 1 for a, b in zip(way, way[1:]))
    assert all(m.cell == start[m.id] for m in movers if m.kind == PALLET)


def test_the_same_seed_moves_them_the_same_way():
    _, free = resolve_map("warehouse-small")
    runs = []
    for _ in range(2):
        rng = np.random.default_rng(7)
        movers = place_movers(free, [PERSON, PERSON, FORKLIFT], set(), rng)
        trace = []
        for _ in range(30):
            movers, _ = step_movers(free, movers, set(), rng)
            trace.append([m.cell for m in movers])
        runs.append(trace)
    assert runs[0] == runs[1] and runs[0][0] != runs[0][-1]


def test_a_walk_goes_along_an_aisle():
    free = np.zeros((3, 12), bool)
    free[1, :] = True                                  # one aisle, 12 cells long
    rng = np.random.default_rng(0)
    movers = [Mover(0, PERSON, (0, 1), heading=(1, 0))]
    for _ in range(11):
        movers, _ = step_movers(free, movers, set(), rng, rules=MoverRules(pause=0))
    assert movers[0].cell == (11, 1)


@pytest.mark.parametrize("before, after, way, how", [
    ({1: (2, 2)}, {1: (3, 2)}, [(3, 2)], "same cell"),              # into a mover that stays
    ({1: (2, 2)}, {1: (3, 2)}, [(4, 2), (3, 2)], "same cell"),      # both into one cell
    ({1: (2, 2)}, {1: (3, 2)}, [(4, 2), (3, 2), (2, 2)], "same cell"),  # across a forklift's way
    ({1: (2, 2)}, {1: (3, 2)}, [(3, 2), (2, 2)], "swap"),           # trading cells
    ({1: (2, 2)}, {1: (2, 3)}, [(3, 2), (4, 2)], None),             # apart
    ({1: (2, 2)}, {1: (2, 2)}, [(3, 2), (4, 2)], None),             # a mover leaving a robot's side
])
def test_contacts_are_a_shared_cell_or_a_swap(before, after, way, how):
    found = contacts(5, before, after, {0: way})
    assert [c.how for c in found] == ([how] if how else [])
    if how:
        assert found[0] == Contact(5, 1, 0, after[1], how)


def test_a_near_miss_is_one_cell_away():
    movers = [Mover(0, PERSON, (5, 5)), Mover(1, FORKLIFT, (9, 9))]
    assert near_misses({1: (6, 6), 2: (7, 5), 3: (9, 8)}, movers) == [(1, 0), (3, 1)]


def test_too_many_movers_for_the_floor_is_one_line():
    free = np.ones((2, 2), bool)
    with pytest.raises(MapError, match="5 movers need 5 free cells"):
        place_movers(free, [PERSON] * 5, set(), np.random.default_rng(0))
