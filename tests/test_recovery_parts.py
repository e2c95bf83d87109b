"""The pure parts of recovery: replanning around stopped robots, and the robots' fault specs."""
import numpy as np
import pytest

from protocol.errors import PlanningError, UavRobotsError
from robot_agents.faults import Fault, parse_fault
from uav_agent.planning.types import Problem
from uav_agent.planning.validator import validate
from uav_agent.recovery import on_goal, replan


def test_replan_goes_around_a_stopped_robot_and_reports_its_goal_unserved():
    free = np.ones((5, 7), dtype=bool)
    goals = [(6, 2), (0, 2), (3, 0)]
    working = {0: (0, 2), 2: (6, 0)}
    blocked = {1: (3, 2)}                       # stopped in the middle of the corridor
    rep = replan(free, goals, working, blocked, planner="lacam", connectivity=4, time_limit=10)
    assert rep.ids == [0, 2]
    paths = rep.result.paths
    obstacles = free.copy()
    obstacles[2, 3] = False
    assert validate(Problem(obstacles, [working[r] for r in rep.ids], rep.result.goals), paths) == []
    assert all((3, 2) not in p for p in paths)
    assert len(rep.unserved) == 1


def test_a_goal_under_a_stopped_robot_cannot_be_served():
    free = np.ones((3, 3), dtype=bool)
    with pytest.raises(PlanningError, match="2 working robots but only 1 goals"):
        replan(free, [(0, 0), (2, 2)], {0: (1, 0), 1: (1, 2)}, {9: (2, 2)}, planner="lacam", connectivity=4,
               time_limit=5)


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
        parse_fault(text)
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
