"""The world's referee: simultaneous moves, refusals, and the no-overlap invariant."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from protocol.errors import UavRobotsError
from sim_world.moves import MoveJudge

OPEN = np.ones((5, 6), dtype=bool)


def judge(positions, free=OPEN, conn=4):
    return MoveJudge(free.copy(), dict(positions), conn)


def test_plain_moves_and_record():
    j = judge({0: (0, 0), 1: (3, 3)})
    out = j.resolve(1, {0: ((0, 0), (1, 0)), 1: ((3, 3), (3, 3))})
    assert out[0].accepted and out[0].cell == (1, 0)
    assert out[1].accepted and out[1].cell == (3, 3)
    j.resolve(2, {0: ((1, 0), (2, 0))})  # robot 1 asked nothing: stays
    assert j.record == {0: [(0, 0), (1, 0), (2, 0)], 1: [(3, 3), (3, 3), (3, 3)]}
    assert j.collisions == 0 and j.refused == []


@pytest.mark.parametrize("to,words", [((-1, 0), "off"), ((0, 5), "off"), ((2, 0), "not a 4-connected"),
                                      ((1, 1), "not a 4-connected")])
def test_static_refusals(to, words):
    j = judge({0: (0, 0)})
    out = j.resolve(1, {0: ((0, 0), to)})
    assert not out[0].accepted and out[0].cell == (0, 0) and words in out[0].reason
    assert j.collisions == 1 and j.refused[0].collision


def test_obstacle_corner_cut_and_wrong_from():
    free = OPEN.copy()
    free[0, 1] = False
    j = judge({0: (0, 0), 1: (3, 3)}, free, conn=8)
    out = j.resolve(1, {0: ((0, 0), (1, 1)), 1: ((2, 2), (2, 3))})
    assert "corner" in out[0].reason and "not at (2, 2)" in out[1].reason
    out = j.resolve(2, {0: ((0, 0), (1, 0))})
    assert "obstacle" in out[0].reason
    out = j.resolve(3, {0: ((0, 0), (2, 2))})
    assert "more than one cell" in out[0].reason
    # A robot wrong about where it stands makes no motion: refused, but nobody was hit.
    assert j.collisions == 3 and j.positions == {0: (0, 0), 1: (3, 3)}
    assert [f.collision for f in j.refused] == [True, False, True, True]


def test_a_skid_lands_elsewhere_without_a_conflict_and_the_robot_is_not_told():
    free = np.ones((6, 6), dtype=bool)
    starts = {r: (r, 0) for r in range(6)}
    j = MoveJudge(free, dict(starts), 4, skid_prob=1.0, seed=1)
    out = j.resolve(1, {r: ((r, 0), (r, 1)) for r in range(6)})
    assert all(o.accepted and o.cell == (r, 1) for r, o in out.items())   # what the robots believe
    assert j.skids and j.collisions == 0
    cells = list(j.positions.values())
    assert len(set(cells)) == len(cells)
    for s in j.skids:
        assert tuple(s["actual"]) == j.positions[s["robot"]] != tuple(s["intended"])


def test_vertex_swap_and_following():
    j = judge({0: (0, 0), 1: (2, 0), 2: (3, 0), 3: (4, 0)})
    # 0 and 1 both into (1, 0); 2 follows 3 which moves on: allowed.
    out = j.resolve(1, {0: ((0, 0), (1, 0)), 1: ((2, 0), (1, 0)), 2: ((3, 0), (4, 0)), 3: ((4, 0), (5, 0))})
    assert not out[0].accepted and not out[1].accepted
    assert out[2].accepted and out[3].accepted and j.positions[2] == (4, 0)
    out = j.resolve(2, {2: ((4, 0), (5, 0)), 3: ((5, 0), (4, 0))})
    assert not out[2].accepted and not out[3].accepted and "swap" in out[2].reason and "swap" in out[3].reason
    assert j.collisions == 4


def test_refusal_cascades_to_followers():
    # 0 moves into an obstacle and stays; 1 follows 0, 2 follows 1: both must be refused in turn.
    free = OPEN.copy()
    free[0, 4] = False
    j = judge({0: (3, 0), 1: (2, 0), 2: (1, 0)}, free)
    out = j.resolve(1, {0: ((3, 0), (4, 0)), 1: ((2, 0), (3, 0)), 2: ((1, 0), (2, 0))})
    assert [out[r].accepted for r in range(3)] == [False, False, False]
    assert j.positions == {0: (3, 0), 1: (2, 0), 2: (1, 0)}


def test_rotation_cycle_is_allowed():
    j = judge({0: (0, 0), 1: (1, 0), 2: (1, 1), 3: (0, 1)})
    out = j.resolve(1, {0: ((0, 0), (1, 0)), 1: ((1, 0), (1, 1)), 2: ((1, 1), (0, 1)), 3: ((0, 1), (0, 0))})
    assert all(o.accepted for o in out.values())


def test_diagonal_crossing_refused_in_8_connected():
    j = judge({0: (0, 0), 1: (1, 0)}, conn=8)
    out = j.resolve(1, {0: ((0, 0), (1, 1)), 1: ((1, 0), (0, 1))})
    assert not out[0].accepted and not out[1].accepted and "crossing" in out[0].reason
    j2 = judge({0: (0, 0), 1: (0, 1)}, conn=8)
    out = j2.resolve(1, {0: ((0, 0), (1, 1)), 1: ((0, 1), (1, 0))})
    assert not out[0].accepted and not out[1].accepted


def test_past_tick_unknown_robot_and_skipped_ticks():
    j = judge({0: (0, 0)})
    j.resolve(1, {0: ((0, 0), (1, 0))})
    out = j.resolve(1, {0: ((1, 0), (2, 0))})
    assert not out[0].accepted and "over" in out[0].reason and j.positions[0] == (1, 0)
    out = j.resolve(4, {0: ((1, 0), (1, 1)), 9: ((0, 0), (0, 1))})
    assert out[0].accepted and not out[9].accepted and "unknown robot 9" in out[9].reason
    assert j.record[0] == [(0, 0), (1, 0), (1, 0), (1, 0), (1, 1)]
    assert j.collisions == 0 and len(j.refused) == 2 and not any(r.collision for r in j.refused)


def test_bad_setup_is_one_line_error():
    with pytest.raises(UavRobotsError, match="both start"):
        judge({0: (0, 0), 1: (0, 0)})
    free = OPEN.copy()
    free[0, 0] = False
    with pytest.raises(UavRobotsError, match="not a free cell"):
        judge({0: (0, 0)}, free)


@st.composite
def worlds(draw):
    w, h = draw(st.integers(2, 6)), draw(st.integers(2, 6))
    free = np.array(draw(st.lists(st.booleans(), min_size=w * h, max_size=w * h)), dtype=bool).reshape(h, w)
    cells = [(x, y) for y in range(h) for x in range(w) if free[y, x]]
    n = draw(st.integers(0, len(cells)))
    starts = draw(st.permutations(cells))[:n]
    conn = draw(st.sampled_from([4, 8]))
    steps = draw(st.lists(st.lists(st.tuples(st.integers(0, max(n - 1, 0)), st.integers(-2, 2),
                                             st.integers(-2, 2), st.booleans()), max_size=12), max_size=8))
    return free, dict(enumerate(starts)), conn, steps


@settings(max_examples=150, deadline=None)
@given(worlds())
def test_no_two_robots_ever_share_a_cell(world):
    free, starts, conn, steps = world
    j = MoveJudge(free, starts, conn)
    for t, moves in enumerate(steps, 1):
        reqs = {}
        for r, dx, dy, lie in moves:
            if r in j.positions:
                x, y = j.positions[r]
                frm = (x + 1, y) if lie else (x, y)
                reqs[r] = (frm, (x + dx, y + dy))
        before = dict(j.positions)
        out = j.resolve(t, reqs)
        cells = list(j.positions.values())
        assert len(set(cells)) == len(cells)
        assert all(free[y, x] for x, y in cells)
        for r, (a, b) in before.items():
            (c, d) = j.positions[r]
            assert max(abs(a - c), abs(b - d)) <= 1 and (conn == 8 or abs(a - c) + abs(b - d) <= 1)
        for r, o in out.items():
            assert o.cell == j.positions[r] and (o.accepted or o.cell == before[r])
        # No swaps and no crossings among executed moves.
        moved = {r: (before[r], j.positions[r]) for r in before if before[r] != j.positions[r]}
        ends = {(a, b) for a, b in moved.values()}
        for a, b in moved.values():
            assert (b, a) not in ends
            if a[0] != b[0] and a[1] != b[1]:
                assert ((b[0], a[1]), (a[0], b[1])) not in ends and ((a[0], b[1]), (b[0], a[1])) not in ends
    assert all(len(c) == j.tick + 1 for c in j.record.values())


def test_a_robot_stopped_by_one_that_slipped_unseen_is_a_safety_stop_not_a_collision():
    # Robot 0 skidded to (2, 0) believing it is at (1, 0); robot 1's plan, right for the floor the
    # robots believe in, moves it into (2, 0), and robot 2 follows robot 1. Both are stopped by the
    # slip, neither by a plan in conflict: recorded, counted as safety stops, no collision.
    j = judge({0: (2, 0), 1: (3, 0), 2: (4, 0)})
    out = j.resolve(1, {0: ((1, 0), (1, 1)), 1: ((3, 0), (2, 0)), 2: ((4, 0), (3, 0))})
    assert not out[0].accepted and "is at (2, 0), not at (1, 0)" in out[0].reason
    assert not out[1].accepted and "slipped there unseen" in out[1].reason
    assert not out[2].accepted and "robot 0 slipped there unseen" in out[2].reason
    assert j.collisions == 0 and j.safety_stops == 2
    assert [f.collision for f in j.refused] == [False, False, False]
    # The same move into a robot that is where it believes is a collision, as before.
    j = judge({0: (2, 0), 1: (3, 0)})
    out = j.resolve(1, {0: ((2, 0), (2, 0)), 1: ((3, 0), (2, 0))})
    assert not out[1].accepted and j.collisions == 1 and j.safety_stops == 0


def test_a_broken_drive_skids_on_every_move_from_its_tick():
    j = MoveJudge(OPEN.copy(), {0: (0, 2), 1: (5, 4)}, 4, skid_robots={0: 2})
    j.resolve(1, {0: ((0, 2), (1, 2)), 1: ((5, 4), (5, 3))})
    assert j.positions[0] == (1, 2) and not j.skids
    for k in (2, 3):
        start = j.positions[0]
        out = j.resolve(k, {0: (start, (start[0] + 1, start[1]))})
        assert out[0].accepted and out[0].cell == (start[0] + 1, start[1])   # told it arrived
        assert j.positions[0] != (start[0] + 1, start[1])                     # it did not
    assert [s["robot"] for s in j.skids] == [0, 0] and j.collisions == 0


def test_a_robot_that_asks_nothing_stops_its_follower_safely():
    # Robot 0 died (it asks nothing this tick); robot 1 follows it into the cell it was to leave.
    j = judge({0: (2, 0), 1: (1, 0)})
    out = j.resolve(1, {1: ((1, 0), (2, 0))})
    assert not out[1].accepted and "robot 0 did not move: a safety stop" in out[1].reason
    assert j.collisions == 0 and j.safety_stops == 1
