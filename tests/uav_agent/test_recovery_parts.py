"""The pure parts of recovery: replanning around stopped robots, and the robots' fault specs."""
import numpy as np
import pytest

from protocol.errors import PlanningError, UavRobotsError
from protocol.faults import ROBOTS, Fault, parse_fault
from uav_agent.planning.types import Problem
from uav_agent.planning.validator import validate
from uav_agent.recovery import on_goal, replan


def test_replan_goes_around_a_stopped_robot_and_reports_its_goal_unserved():
    free = np.ones((5, 7), dtype=bool)
    goals = [(6, 2), (0, 2), (3, 0)]
    working = {0: (0, 2), 2: (6, 0)}
    blocked = {1: (3, 2)}                       # stopped in the middle of the corridor
    rep = replan(free, goals, working, blocked, planner="lacam", connectivity=4, time_limit=10)
    assert rep.ids == [0, 2] and not rep.stranded and not rep.pinned
    obstacles = free.copy()
    obstacles[2, 3] = False
    paths = [rep.paths[r] for r in rep.ids]
    assert validate(Problem(obstacles, [working[r] for r in rep.ids], [rep.goals[r] for r in rep.ids]), paths) == []
    assert all((3, 2) not in p for p in paths)
    assert len(rep.unserved) == 1


def test_a_robot_left_without_a_goal_is_held_and_the_others_planned():
    # The goal (2, 2) is under a stopped robot: two working robots, one open goal. One is held where
    # it stands (stranded), the nearer one gets the goal; before, the whole repair failed.
    free = np.ones((3, 3), dtype=bool)
    rep = replan(free, [(0, 0), (2, 2)], {0: (1, 0), 1: (1, 2)}, {9: (2, 2)}, planner="lacam", connectivity=4,
                 time_limit=5)
    assert rep.goals == {0: (0, 0)} and list(rep.stranded) == [1]
    assert "1 open goal(s)" in rep.stranded[1]


def test_a_walled_in_robot_is_stranded_not_the_mission():
    free = np.ones((5, 5), dtype=bool)
    free[:, 2] = False                          # a wall: robot 1 on the left, every goal on the right
    rep = replan(free, [(3, 0), (4, 4)], {0: (4, 0), 1: (0, 0)}, {}, planner="lacam", connectivity=4,
                 time_limit=5)
    assert rep.ids == [0] and "no open goal is reachable from (0, 0)" in rep.stranded[1]
    with pytest.raises(PlanningError, match="no working robot can reach an open goal"):
        replan(free, [(3, 0)], {1: (0, 0)}, {}, planner="lacam", connectivity=4, time_limit=5)


def test_a_robot_verified_on_its_goal_stays_there():
    # Robot 0 stands verified on (2, 1), a goal robot 1 is nearer to; the optimal assignment alone
    # would swap their goals, undoing an arrival the camera already confirmed.
    free = np.ones((3, 5), dtype=bool)
    goals = [(2, 1), (4, 1)]
    working = {0: (2, 1), 1: (1, 1)}
    free[0, :] = free[2, :] = True
    rep = replan(free, goals, working, {}, planner="lacam", connectivity=4, time_limit=5, pinned={0: (2, 1)})
    assert rep.pinned == [0] and rep.paths[0] == [(2, 1)] and rep.goals[1] == (4, 1)
    assert (2, 1) not in rep.paths[1]


def test_on_goal():
    assert on_goal({1: (2, 2), 2: (0, 0)}, {1: (2, 2), 2: (1, 1), 3: (0, 1)}) == {1: True, 2: False, 3: False}


@pytest.mark.parametrize("text, fault", [
    ("crash:3@10", Fault("crash", 3, 10)),
    ("stall:0@2:5", Fault("stall", 0, 2, 5)),
    ("liar:7", Fault("liar", 7)),
])
def test_fault_specs(text, fault):
    assert parse_fault(text) == fault and str(fault) == text


def test_a_stall_is_silent_only_for_its_ticks():
    f = parse_fault("stall:0@2:3")
    assert [f.silent_at(k) for k in range(1, 7)] == [False, True, True, True, False, False]


@pytest.mark.parametrize("text", ["crash:3", "crash:x@1", "stall:1@0:3", "stall:1@2:0", "slip:0.1", "liar"])
def test_bad_fault_specs_are_one_line(text):
    with pytest.raises(UavRobotsError, match="--fault") as e:
        parse_fault(text, ROBOTS)
    assert "\n" not in str(e.value)


def test_a_mode_the_mission_never_commands_is_a_vehicle_fault():
    from types import SimpleNamespace

    from uav_agent.watch import VehicleWatch

    flight = SimpleNamespace(armed=True, in_air=True, flight_mode="HOLD")
    watch = VehicleWatch(flight, lambda why: None, period_s=60)
    try:
        for mine in ("HOLD", "TAKEOFF"):
            flight.flight_mode = mine
            assert watch._check() is None
        # a ground station starting its own mission, or a pilot taking the sticks, takes the vehicle
        for theirs in ("MISSION", "POSCTL", "RETURN_TO_LAUNCH", "LAND", "OFFBOARD"):
            flight.flight_mode = theirs
            assert f"switched to {theirs} mode" in watch._check()
    finally:
        watch.close()


def test_the_watch_knows_the_autopilot_and_the_climb():
    from types import SimpleNamespace

    from uav_agent.watch import VehicleWatch

    flight = SimpleNamespace(armed=True, in_air=True, flight_mode="OFFBOARD", autopilot="ARDUPILOT",
                             battery_pct=9.0, status_text="Critical battery level!")
    watch = VehicleWatch(flight, lambda why: None, period_s=60)
    try:
        # MAVSDK names ArduCopter's GUIDED, the mode a companion flies it in, OFFBOARD
        assert watch._taken() == (None, None)
        flight.autopilot = "PX4"
        assert watch._taken()[0] == "OFFBOARD"
        flight.flight_mode = "RETURN_TO_LAUNCH"
        taken, why = watch._taken()
        assert taken == "RETURN_TO_LAUNCH"
        assert why.endswith("(battery 9 %; the autopilot says 'Critical battery level!')"), why
        # taking off: on the ground is no fault until the vehicle has been in the air
        flight.flight_mode, flight.in_air = "TAKEOFF", False
        watch.expect_airborne(True, taking_off=True)
        assert watch._taken() == (None, None)
        flight.in_air = True
        assert watch._taken() == (None, None)
        flight.in_air = False
        assert watch._taken()[0] == "on the ground"
    finally:
        watch.close()


def test_an_abort_lands_off_the_floor_beyond_its_nearest_corner():
    from uav_agent.landing import MIN_ALT_M, OFF_FLOOR_CELLS as off, abort_spot

    assert abort_spot(-15.0, 20.0, 12.0, 24, 18, 1.0) == (-18 - off, 24 + off, 12.0)   # the south-east corner
    assert abort_spot(-1.0, 1.0, 1.0, 24, 18, 1.0) == (off, -off, MIN_ALT_M)          # north-west, high enough
    assert abort_spot(-100.0, 0.0, 50.0, 450, 450, 2.0) == (2 * off, -2 * off, 50.0)  # cells of 2 m
