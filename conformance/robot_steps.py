"""The robot suite's shared steps: driving a robot under test through a plan, and the bounds it is held to."""
from __future__ import annotations

import time

from protocol.messages import Plan
from protocol.codec import encode


EXIT_S = 5.0
QUIET_S = 0.5  # how long "nothing more arrives" is watched for
MOVE_TIMEOUT_S = 5.0  # docs/protocol.md, QoS: a robot waits this long for the world's answer to a move


def path_at(path, k):
    return tuple(path[min(k, len(path) - 1)])


def run_ticks(uav, world, rid, plan_id, path, ticks, timeout):
    """Ticks 1..ticks in lockstep, as the UAV's barrier does; returns the states."""
    states = []
    for k in range(1, ticks + 1):
        uav.tick(k, ticks, plan_id)
        st = uav.state_at(rid, k, timeout)
        assert st is not None, f"no RobotState for tick {k} within {timeout:g} s"
        states.append(st)
    return states


def accepted(uav, rid, plan_id, path, timeout):
    uav.plan(rid, plan_id, path)
    ack = uav.ack_for(rid, plan_id, timeout)
    assert ack is not None, f"no PlanAck for plan {plan_id} within {timeout:g} s"
    assert ack.ok, f"a valid plan was refused: {ack.error}"
    return ack


def exits(proc, seconds):
    try:
        proc.wait(seconds)
        return True
    except Exception:  # noqa: BLE001 - TimeoutExpired
        return False


def wrong_version(msg) -> bytes:
    return encode(msg).replace(b'"v":1', b'"v":99', 1)


def pool_with_plans(spawn, cmd: str, uav, timeout: float, plans: dict[int, str], paths: dict[int, list]) -> list[int]:
    """A pool hosting the robots of `plans` (robot -> plan id), each of which has acknowledged its plan."""
    ids = sorted(plans)
    proc = spawn(cmd, ids)
    assert uav.until(lambda: set(ids) <= uav.alive or proc.poll() is not None, timeout), \
        f"the pool declared tokens {sorted(uav.alive)}, expected {ids}"
    for r in ids:
        accepted(uav, r, plans[r], paths[r], timeout)
    return ids


POOL_PATHS = {0: [(2, 2), (3, 2), (3, 3)], 1: [(6, 6), (6, 5), (6, 5)]}   # by offset from --robot-id


def noncanonical_plan_is_dropped(uav, rid, timeout) -> None:
    k = uav.keys
    uav.transport.put(f"{k.prefix}/robot/00{rid}/plan", encode(Plan(robot=rid, plan_id="p-zeros", path=[(2, 2)],
                                                                     goal=(2, 2))))
    time.sleep(QUIET_S)
    assert not any(a.plan_id == "p-zeros" for a in uav.acks.get(rid, [])), \
        f"a plan on robot/00{rid}/plan was taken: that key names no robot"
    accepted(uav, rid, "p-canonical", [(2, 2)], timeout)
