"""What the fake robots do wrong on purpose, and how: the faults a UAV must survive and the junk it must drop."""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from protocol.grid import Cell
from protocol.keys import Keys
from protocol.messages import Done, Message, RobotState, StateBatch, Tick
from protocol.codec import encode

from .fleet_state import FakeRobot, Observed
from .options import CALM_TICKS, MUST_DROP

if TYPE_CHECKING:
    from protocol.transport import Transport


@dataclass(frozen=True)
class Misbehaviour:
    """What the fake robots (and the site) do wrong on purpose (robot ids; by default everyone keeps the contract)."""
    refuse: frozenset[int] = frozenset()       # answer the plan with PlanAck(ok=false)
    silent_from: dict[int, int] = field(default_factory=dict)  # robot -> first tick it executes but never reports
    late: frozenset[int] = frozenset()         # declare the liveliness token only when the suite says so
    absent: frozenset[int] = frozenset()       # never declare the liveliness token (the world has the robot)
    garbage: frozenset[int] = frozenset()      # also put garbage, wrong-version, forged and future messages on its keys
    liar: frozenset[int] = frozenset()         # never move, but report every tick as done to plan and raise Done
    deaf: frozenset[int] = frozenset()         # ignore the first `deaf_puts` puts of the first plan it receives
    deaf_puts: int = 1
    deaf_repair: frozenset[int] = frozenset()  # ignore every put of the first repair plan (start_tick > 0) it receives
    mute: frozenset[int] = frozenset()         # arrive, but never raise Done
    lost_at: dict[int, int] = field(default_factory=dict)      # robot -> tick after whose state its token vanishes
    vanish_at: dict[int, int] = field(default_factory=dict)    # robot -> tick on whose arrival it vanishes, mid-tick
    error_at: dict[int, int] = field(default_factory=dict)     # robot -> tick it cannot execute: stays, status error
    deviate_at: dict[int, int] = field(default_factory=dict)   # robot -> from this tick, once: stays where its plan moves it
    stuck_from: dict[int, int] = field(default_factory=dict)   # robot -> from this tick it never moves (honest states)
    stall: dict[int, tuple[int, int]] = field(default_factory=dict)  # robot -> (tick, n): frozen for n ticks, then back
    rtl_at: int = 0                            # at this tick a ground station commands RTL on the vehicle (0: never)


def _wrong_version(msg: Message) -> bytes:
    return encode(msg).replace(b'"v":1', b'"v":99', 1)


def junk(msg: Message, forged: Message | None) -> list[bytes]:
    """Payloads a UAV must drop on a robot's key: garbage, a bad field, a wrong version, another robot's message."""
    name = type(msg).__name__.encode()
    bad_field = json.loads(encode(msg))
    bad_field["robot"] = str(bad_field["robot"])
    out = [b"", b"\x00\xff garbage", b"{}", b"[1,2,3]", b'{"type":"' + name + b'","v":1}',
           json.dumps(bad_field).encode(), _wrong_version(msg)]
    if forged is not None:
        out.append(encode(forged))
    return out


class Misbehaving:
    """The fleet's faults, made on purpose as `behaviour` says: a mixin of `FakeFleet`, on its robots and log."""
    keys: Keys
    transport: Transport
    behaviour: Misbehaviour
    robots: dict[int, FakeRobot]
    log: Observed

    def _asks(self, robot: FakeRobot, k: int) -> bool:
        """Whether the robot asks the world for a move at tick k (a frozen, lost or lying one does not)."""
        return not robot.gone and robot.frozen == 0 and robot.rid not in self.behaviour.liar

    def _stays_on_purpose(self, robot: FakeRobot, k: int, targets: dict[int, Cell]) -> str:
        """Why the robot stays at tick k against its plan ('' if it follows it)."""
        b, rid = self.behaviour, robot.rid
        if k == b.error_at.get(rid):
            return "error"
        if k >= b.stuck_from.get(rid, k + 1) and targets[rid] != robot.cell:
            return "stuck"
        if (k >= b.deviate_at.get(rid, k + 1) and not robot.deviated and targets[rid] != robot.cell and self._calm(k)
                and robot.plan is not None and all(t != robot.cell for r, t in targets.items() if r != rid)):
            robot.deviated = True   # nobody was to follow it into its cell: staying blocks no one
            return "deviation"
        return ""

    def _calm(self, k: int) -> bool:
        """No fault the harness made in the last 3 ticks: a scheduled deviation or stall waits for it, so that
        each fault gets a repair of its own (one a UAV could not make for another fault's sake)."""
        return all(tick <= k - CALM_TICKS for _, _, tick, _ in self.log.faults)

    def _make_way(self, targets: dict[int, Cell]) -> None:
        """Robots that would move into a cell whose robot stays (stuck, frozen, gone, on purpose) stay too:
        the world would refuse them and count a collision the UAV could not have foreseen."""
        held = {r.cell for r in self.robots.values() if r.rid not in targets or targets[r.rid] == r.cell}
        changed = True
        while changed:
            changed = False
            for rid, to in targets.items():
                here = self.robots[rid].cell
                if to != here and to in held:
                    targets[rid] = here
                    held.add(here)
                    changed = True

    def _vanish(self, robot: FakeRobot, kind: str, k: int) -> None:
        with self.cv:
            robot.gone = True
            token, robot.token = robot.token, None
        if token is not None:
            token.close()
        self._fault(kind, robot.rid, k)

    def _lie(self, robot: FakeRobot, tick: Tick) -> None:
        """States that follow the plan and a Done at its end, from a robot that never asks the world to move:
        only the UAV's camera can tell."""
        plan, claimed = robot.plan, self._target(robot, tick)
        over = plan is not None and plan.plan_id == tick.plan_id and tick.k - robot.base >= len(plan.path) - 1
        with self.cv:
            robot.reported.add(tick.k)
        self._put(robot, self.keys.state(robot.rid), RobotState(
            robot=robot.rid, tick=tick.k, cell=claimed, status="done" if over else "stepping",
            plan_id=plan.plan_id if plan else ""))
        if over and robot.done_for != plan.plan_id:
            robot.done_for = plan.plan_id
            self._put(robot, self.keys.done(robot.rid), Done(robot=robot.rid, tick=tick.k, cell=claimed))

    def _garbage(self, robot: FakeRobot, state: RobotState) -> None:
        """Before its state of tick k (k <= 3): junk, another robot's state and Done, and a batch naming
        another robot on its keys; at k = 2 also well-formed states for ticks not yet put (3, and 7 with
        an error). A UAV must drop every one of them."""
        rid, k, other = robot.rid, state.tick, self._other(robot.rid)
        bad = dataclasses.replace(state, tick=k + 5, status="error", error=MUST_DROP)
        for payload in junk(bad, dataclasses.replace(bad, robot=other, tick=k) if other is not None else None):
            self.transport.put(self.keys.state(rid), payload)
        fake_done = Done(robot=rid, tick=k, cell=robot.cell)
        for payload in junk(fake_done, dataclasses.replace(fake_done, robot=other) if other is not None else None):
            self.transport.put(self.keys.done(rid), payload)
        if other is not None:
            # A StateBatch on this robot's own batch key with an entry for another robot: an error the
            # key does not name (a UAV reading batches drops it; one that does not, never sees it).
            entry = (other, self.robots[other].cell, "error", state.plan_id, MUST_DROP)
            self.transport.put(self.keys.states_as([rid]), encode(StateBatch(tick=k, states=[entry])))

    def _future(self, robot: FakeRobot, state: RobotState, tick: Tick) -> None:
        """Well-formed states for ticks the UAV has not put: the next (on its plan's cell, as if reported
        early) and one five ahead (an error). Neither reports anything."""
        plan, k = robot.plan, state.tick
        nxt = self._target(robot, dataclasses.replace(tick, k=k + 1)) if plan is not None else robot.cell
        self._put(robot, self.keys.state(robot.rid), dataclasses.replace(state, tick=k + 1, cell=nxt))
        self._put(robot, self.keys.state(robot.rid), dataclasses.replace(state, tick=k + 5, status="error",
                                                                          error=MUST_DROP))
