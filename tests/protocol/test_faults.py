"""The fault catalogue's window faults (camera.off, camera.stuck, link.mavlink): their grammar, checks,
help and routing, pure; and what a world or vehicle process makes of them before it starts."""
from __future__ import annotations

import pytest

from protocol.errors import UavRobotsError
from protocol.faults import (
    VEHICLE,
    WORLD,
    Fault,
    help_line,
    parse_fault,
    split_faults,
    usage,
)


@pytest.mark.parametrize("text, kind, injector", [
    ("camera-off:20+40", "off", WORLD),
    ("camera-stuck:0+5", "stuck", WORLD),
    ("mavlink-loss:10+300", "mavlink", VEHICLE),
])
def test_window_faults_parse_round_trip_and_go_to_their_process(text, kind, injector):
    f = parse_fault(text)
    assert (f.kind, f.injector, str(f)) == (kind, injector, text)
    assert f == parse_fault(text, injector)
    assert split_faults([text])[injector] == [f]


def test_a_window_acts_from_its_start_for_its_duration():
    f = parse_fault("camera-off:20+40")
    assert (f.seconds, f.duration) == (20, 40)
    assert [f.active_at(t) for t in (19.9, 20.0, 59.9, 60.0)] == [False, True, True, False]


@pytest.mark.parametrize("text, words", [
    ("camera-off:20+0", "DURATION is at least 1 simulated second"),
    ("camera-stuck:5", "give "),
    ("mavlink-loss:-1+3", "give "),
    ("camera-off:1.5+3", "give "),
])
def test_a_bad_window_is_one_line(text, words):
    with pytest.raises(UavRobotsError, match="--fault") as e:
        parse_fault(text)
    assert words in str(e.value) and "\n" not in str(e.value)


def test_each_process_takes_only_its_own():
    with pytest.raises(UavRobotsError, match="battery:PCT@SECONDS or mavlink-loss:SECONDS\\+DURATION"):
        parse_fault("camera-off:1+2", VEHICLE)
    with pytest.raises(UavRobotsError):
        parse_fault("mavlink-loss:1+2", WORLD)
    assert "camera-off:SECONDS+DURATION" in usage(WORLD) and "camera-stuck:SECONDS+DURATION" in usage(WORLD)
    line = help_line()
    world, vehicle = line.split("the world's:")[1].split("the vehicle's:")
    assert "camera-off:" in world and "camera-stuck:" in world and "mavlink-loss:" in vehicle


def test_window_faults_are_no_robots():
    assert Fault("off", seconds=1, duration=2).robot is None
