"""Robot conformance: a robot's life, from its token to its exit (docs/protocol.md, Startup order, End of mission).

The suite plays hub, UAV and world around the robot under test, started from
`--robot-cmd` (conftest.py). See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import signal
import time

from conformance import FakeUav, Hub, free_endpoint, signal_group, start_robot, stop_process
from conformance.robot_steps import EXIT_S, accepted, exits, wrong_version
from protocol.keys import new_fleet_name
from protocol.messages import MissionEnd, Tick
from protocol.codec import encode


def test_liveliness_token_appears(spawn, uav, rid, timeout):
    proc = spawn()
    assert uav.until(lambda: rid in uav.alive, timeout), f"no liveliness token within {timeout:g} s"
    assert proc.poll() is None, f"the robot exited with code {proc.returncode}"


def test_restart_gets_a_fresh_token(spawn, uav, rid, timeout):
    """A robot that is killed and restarted comes back alive on the same id."""
    first = spawn()
    assert uav.until(lambda: rid in uav.alive, timeout)
    signal_group(first, signal.SIGKILL)
    first.wait(5)
    assert uav.until(lambda: rid not in uav.alive, timeout), "the dead robot's token did not go away"
    spawn()
    assert uav.until(lambda: rid in uav.alive, timeout)


def test_a_mission_end_put_as_the_token_appears_is_received(robot, uav, rid):
    """docs/protocol.md, Startup order: `mission/end` is subscribed before the token is declared."""
    uav.end(True, "conformance")
    assert exits(robot, EXIT_S), f"still running {EXIT_S:g} s after a MissionEnd put as its token appeared"


def test_serves_before_it_has_seen_the_uav(spawn, hub, world, rid, timeout):
    """docs/protocol.md, End of mission: a robot exits when `alive/uav` disappears *after having been seen*;
    started before any UAV, it waits and serves."""
    quiet = FakeUav(hub.transport, hub.keys, announce=False)
    try:
        proc = spawn()
        assert quiet.until(lambda: rid in quiet.alive or proc.poll() is not None, timeout), "no liveliness token"
        time.sleep(1.0)
        assert proc.poll() is None, f"the robot exited ({proc.returncode}) though no UAV had come and gone"
        accepted(quiet, rid, "p-early", [(2, 2), (3, 2)], timeout)
    finally:
        quiet.close()


def test_waits_for_a_router_at_start(robot_cmd, rid, timeout, tmp_path):
    """docs/protocol.md, Timeouts and waits: a robot waits up to 20 s for a router at start."""
    endpoint, fleet = free_endpoint(), new_fleet_name()
    proc = start_robot(robot_cmd, rid, fleet, endpoint, tmp_path / "robot-early.log")
    try:
        time.sleep(2.0)
        assert proc.poll() is None, f"the robot exited ({proc.returncode}) 2 s after it started without a router"
        with Hub(fleet, endpoint=endpoint) as hub:
            uav = FakeUav(hub.transport, hub.keys)
            try:
                assert uav.until(lambda: rid in uav.alive or proc.poll() is not None, timeout + 5.0), \
                    "no liveliness token after the router came up"
                assert proc.poll() is None, f"the robot exited ({proc.returncode})"
            finally:
                uav.close()
    finally:
        stop_process(proc)


def test_exits_on_mission_end(robot, uav, rid, timeout):
    accepted(uav, rid, "p-end", [(2, 2)], timeout)
    uav.end(True, "conformance")
    assert exits(robot, EXIT_S), f"still running {EXIT_S:g} s after MissionEnd"
    assert robot.returncode == 0
    assert uav.until(lambda: rid not in uav.alive, timeout), "liveliness token left behind"


def test_exits_on_sigterm(robot, uav, rid, timeout):
    robot.send_signal(signal.SIGTERM)
    assert exits(robot, EXIT_S), f"still running {EXIT_S:g} s after SIGTERM"
    assert robot.returncode == 0, f"exit code {robot.returncode}: a robot exits 0 on SIGTERM, closing its session"


def test_exits_when_the_uav_goes_away(robot, uav, rid):
    uav.leave()
    assert exits(robot, EXIT_S), f"still running {EXIT_S:g} s after the UAV's liveliness token went away"


def test_exits_on_sigint(robot, uav, rid, timeout):
    robot.send_signal(signal.SIGINT)
    assert exits(robot, EXIT_S), f"still running {EXIT_S:g} s after SIGINT"
    assert robot.returncode == 0, f"exit code {robot.returncode}: a robot exits 0 on SIGINT, closing its session"


def test_exits_with_a_move_query_pending(robot, uav, world, rid, timeout):
    """docs/protocol.md, End of mission: within 5 s, a move query still waiting for its answer abandoned."""
    world.hold = True
    accepted(uav, rid, "p-pending", [(2, 2), (3, 2)], timeout)
    uav.tick(1, 1, "p-pending")
    assert world.until(lambda: bool(world.requests_for(rid, 1)), timeout), "no move asked for tick 1"
    uav.end(True, "conformance")
    assert exits(robot, EXIT_S), f"still running {EXIT_S:g} s after MissionEnd, its move query pending"
    assert not uav.states.get(rid), f"a state for the abandoned tick: {uav.states.get(rid)}"


def test_an_undecodable_mission_end_is_dropped(robot, uav, world, rid, timeout):
    """docs/protocol.md, End of mission: a MissionEnd that does not decode is dropped like any other message."""
    k = uav.keys
    for payload in (b"", b"{}", b"end", wrong_version(MissionEnd(completed=True)),
                    b'{"type":"MissionEnd","v":1,"completed":"yes"}', encode(Tick(k=1, ticks=1, plan_id="x"))):
        uav.transport.put(k.mission_end, payload)
    time.sleep(1.0)
    assert robot.poll() is None, f"the robot exited ({robot.returncode}) on a mission end that does not decode"
    accepted(uav, rid, "p-still-here", [(2, 2)], timeout)
