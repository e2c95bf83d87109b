"""The UAV's fleet link refuses garbage and forged messages and keeps its state."""

import pytest

from protocol.codec import encode
from protocol.keys import Keys
from protocol.messages import Done, PlanAck, RobotState
from protocol.transport import MemoryBus, MemoryTransport
from uav_agent.fleet import FleetLink


def test_garbage_and_forgery_are_refused_state_kept():
    bus = MemoryBus()
    keys = Keys("t")
    link = FleetLink(MemoryTransport(bus), keys)
    link.clock = 3          # the mission has put Tick(3)
    robot = MemoryTransport(bus)
    tok = robot.announce(keys.alive_robot(1))
    robot.put(keys.state(1), encode(RobotState(robot=1, tick=3, cell=(2, 2), status="stepping")))
    robot.put(keys.state(1), b"\x00garbage")
    robot.put(keys.state(1), b'{"type":"RobotState","v":7}')
    robot.put(keys.state(1), encode(RobotState(robot=2, tick=9, cell=(5, 5), status="stepping")))  # forged
    # a state for a tick the mission has not reached: it used to pin the robot's cell for good
    robot.put(keys.state(1), encode(RobotState(robot=1, tick=100_000, cell=(6, 6), status="stepping")))
    robot.put(keys.ack(1), encode(PlanAck(robot=1, plan_id="p", ok=True)))
    robot.put(keys.done(1), encode(Done(robot=1, tick=3, cell=(2, 2))))
    assert link.rejected == 4
    assert link.last_tick == {1: 3} and link.cells == {1: (2, 2)}
    assert link.acks[1].ok and 1 in link.done and link.alive == {1}
    tok.close()
    assert link.lost == {1} and "lost" in link.lost_among([1])
    link.close()


@pytest.mark.slow
def test_a_fleet_still_coming_up_extends_the_start_up_wait_a_stopped_one_does_not():
    import threading
    import time

    import pytest

    from protocol.errors import MissionError

    bus = MemoryBus()
    keys = Keys("t")
    link = FleetLink(MemoryTransport(bus), keys)
    robot = MemoryTransport(bus)
    tokens = []

    def come_up():   # one robot every 0.3 s: each resets a 0.5 s wait
        for rid in range(5):
            time.sleep(0.3)
            tokens.append(robot.announce(keys.alive_robot(rid)))

    t = threading.Thread(target=come_up)
    t.start()
    start = time.monotonic()
    link.wait_until(lambda: len(link.alive) >= 5, 0.5, lambda: "never", progress=lambda: len(link.alive), longest=10)
    assert len(link.alive) == 5 and time.monotonic() - start >= 1.4   # well past one 0.5 s wait
    t.join()
    with pytest.raises(MissionError, match="only 5 of 6"):
        link.wait_until(lambda: len(link.alive) >= 6, 0.5, lambda: f"only {len(link.alive)} of 6",
                        progress=lambda: len(link.alive), longest=10)
    for tok in tokens:
        tok.close()
    link.close()
