"""The UAV's view of the fleet over the transport: who is alive, acks, per-tick states, done flags.

Callbacks only record what arrived (checked against the key they came on, so a
robot cannot speak for another); the mission thread waits on the condition.
"""
from __future__ import annotations

import threading
import time
from typing import Callable

from protocol.codec import decode
from protocol.errors import MissionError, ProtocolError, UavRobotsError
from protocol.keys import Keys, ids_of_states_key, robot_id_from_key
from protocol.log import Throttled
from protocol.messages import Done, PlanAck, RobotState, StateBatch
from protocol.transport import Transport


class FleetLink:
    def __init__(self, transport: Transport, keys: Keys, members: int | None = None) -> None:
        self.transport, self.keys = transport, keys
        self.cv = threading.Condition()
        # The fleet's robot ids (0 .. members-1; None: whoever shows up). On an open fleet anyone may
        # put on any robot's key: what names a robot outside the fleet is dropped and counted, never
        # reported (a stranger's Done for robots 0-63 put ids outside an 8-robot fleet in the report).
        self.members = members
        self.foreign = 0
        self.alive: set[int] = set()
        self.lost: set[int] = set()
        self.world_alive = False
        self.world_seen = False
        # Why every wait must end now (the vehicle is not the mission's any more), or None.
        self.interrupt: Callable[[], str | None] = lambda: None
        self.observers: set[str] = set()        # recorders and views that said they listen
        self.acks: dict[int, PlanAck] = {}
        self.last_tick: dict[int, int] = {}
        self.cells: dict[int, tuple[int, int]] = {}
        self.errors: dict[int, str] = {}
        self.done: dict[int, Done] = {}
        self.heard: dict[int, float] = {}       # when each robot last showed life (a state, or its token)
        # While wait_tick runs: the tick awaited and the robots that have not reported it. A state
        # wakes the waiter only when it completes the tick or reports an error: waking it for each
        # of N states, to scan N robots, made a tick cost N^2.
        self._awaited: tuple[int, set[int]] | None = None
        # The last tick awaited: a robot reports tick k after Tick(k), so a state for a tick beyond
        # the next is not a robot's. Believed, one state for tick 100,000 pinned that robot's cell
        # and counted it as reported for every tick after (a forged state, found by fuzzing).
        self.clock = 0
        self._warn = Throttled("uav")
        self._handles = [
            transport.subscribe(keys.all_acks, self._on_ack),
            transport.subscribe(keys.all_states, self._on_state, inline=True),
            transport.subscribe(keys.all_state_batches, self._on_state_batch, inline=True),
            transport.subscribe(keys.all_done, self._on_done, inline=True),
            transport.watch_alive(keys.alive_robots, self._on_robot_alive),
            transport.watch_alive(keys.alive_world, self._on_world_alive),
            transport.watch_alive(keys.alive_observers, self._on_observer_alive),
        ]

    @property
    def rejected(self) -> int:
        return self._warn.count

    def _reject(self, key: str, why: str) -> None:
        self._warn(f"ignored message on {key}: {why}")

    @property
    def world_gone(self) -> bool:
        """The world's token was up and has vanished (the world died or left)."""
        return self.world_seen and not self.world_alive

    def _member(self, robot: int) -> bool:
        return self.members is None or 0 <= robot < self.members

    def _foreign(self, key: str, robots) -> None:
        self.foreign += 1
        self._reject(key, f"robot(s) {list(robots)[:5]} are not in this fleet of {self.members}")

    def _decode(self, key: str, payload: bytes, cls):
        rid = robot_id_from_key(key)
        try:
            msg = decode(payload, cls)
        except ProtocolError as exc:
            self._reject(key, str(exc))
            return None
        if msg.robot != rid:
            self._reject(key, f"message for robot {msg.robot} sent on robot {rid}'s key")
            return None
        if not self._member(msg.robot):
            self._foreign(key, [msg.robot])
            return None
        return msg

    def _on_ack(self, key: str, payload: bytes) -> None:
        msg = self._decode(key, payload, PlanAck)
        if msg is not None:
            with self.cv:
                self.acks[msg.robot] = msg
                self.cv.notify_all()

    def _from_the_future(self, key: str, tick: int) -> bool:
        if tick <= self.clock:   # the mission puts Tick(k) only after its clock says k
            return False
        self._reject(key, f"a state for tick {tick}, and the mission is at tick {self.clock}")
        return True

    def _on_state(self, key: str, payload: bytes) -> None:
        msg = self._decode(key, payload, RobotState)
        if msg is not None and not self._from_the_future(key, msg.tick):
            with self.cv:
                self._take_state(msg.robot, msg.tick, msg.cell, msg.status, msg.error)

    def _on_state_batch(self, key: str, payload: bytes) -> None:
        """A pool's states of one tick: each judged as a RobotState, for the robots its key names only."""
        try:
            ids = set(ids_of_states_key(self.keys, key))
            msg = decode(payload, StateBatch, len(ids))
        except (ProtocolError, UavRobotsError) as exc:
            self._reject(key, str(exc))
            return
        if self._from_the_future(key, msg.tick):
            return
        foreign = [s[0] for s in msg.states if s[0] not in ids]
        if foreign:
            self._reject(key, f"states of robot(s) {foreign[:5]} the key does not name")
        ids = {r for r in ids if self._member(r)}
        with self.cv:
            # The entries as they are: a RobotState object per robot was a third of the time here.
            for robot, cell, status, _plan, error in msg.states:
                if robot in ids:
                    self._take_state(robot, msg.tick, cell, status, error)

    def _take_state(self, robot: int, tick: int, cell: tuple[int, int], status: str, error: str) -> None:
        """One robot's state (under the lock)."""
        if tick >= self.last_tick.get(robot, -1):
            self.last_tick[robot] = tick
            self.cells[robot] = cell
        self.heard[robot] = time.monotonic()
        wake = self._awaited is None
        if status == "error":
            self.errors[robot] = error or "robot reported an error"
            wake = True
        elif not wake and tick >= self._awaited[0]:
            late = self._awaited[1]
            late.discard(robot)
            wake = not late
        if wake:
            self.cv.notify_all()

    def _on_done(self, key: str, payload: bytes) -> None:
        msg = self._decode(key, payload, Done)
        if msg is not None:
            with self.cv:
                self.done[msg.robot] = msg   # the latest: a replanned robot raises Done again
                self.cv.notify_all()

    def _on_robot_alive(self, key: str, alive: bool) -> None:
        rid = robot_id_from_key(key)
        if rid is None:
            return
        if not self._member(rid):
            if alive:
                self._foreign(key, [rid])
            return
        with self.cv:
            if alive:
                self.alive.add(rid)
                self.lost.discard(rid)
                self.heard[rid] = time.monotonic()
            elif rid in self.alive:
                self.alive.discard(rid)
                self.lost.add(rid)
            self.cv.notify_all()

    def _on_world_alive(self, key: str, alive: bool) -> None:
        with self.cv:
            self.world_alive = alive
            self.world_seen |= alive
            self.cv.notify_all()

    def _on_observer_alive(self, key: str, alive: bool) -> None:
        with self.cv:
            (self.observers.add if alive else self.observers.discard)(key)
            self.cv.notify_all()

    def wait_until(self, ready: Callable[[], bool], timeout: float, failure: Callable[[], str],
                   abort: Callable[[], str | None] | None = None, progress: Callable[[], object] | None = None,
                   longest: float | None = None) -> None:
        """Block until `ready()` (evaluated under the lock), or raise MissionError with `failure()`.

        With `progress`, `timeout` counts from its last change (a slow machine still bringing up
        robots is not a dead one), up to `longest` in all."""
        start = time.monotonic()
        deadline = start + timeout
        last = progress() if progress is not None else None
        with self.cv:
            while not ready():
                if (why := self.interrupt()) or (abort is not None and (why := abort())):
                    raise MissionError(why)
                if progress is not None and (now := progress()) != last:
                    last = now
                    deadline = min(time.monotonic() + timeout, start + (longest or timeout))
                left = deadline - time.monotonic()
                if left <= 0:
                    raise MissionError(failure())
                self.cv.wait(min(left, 0.5))

    def wait_tick(self, robots: list[int], k: int, timeout: float, interrupt: Callable[[], bool]) -> dict[str, list[int]]:
        """Wait until every robot reported tick k; returns what went wrong instead (empty: nothing).

        lost: liveliness gone; error: reported status error; stalled: no state for k within `timeout`.
        `interrupt()` ends the wait early (a vehicle fault), with nothing reported.
        """
        deadline = time.monotonic() + timeout
        with self.cv:
            self.clock = max(self.clock, k)
            late = {r for r in robots if self.last_tick.get(r, -1) < k}
            self._awaited = (k, late)
            try:
                while True:
                    lost = sorted(set(robots) & self.lost)
                    error = sorted(r for r in robots if r in self.errors and r not in lost)
                    if lost or error:
                        return {"lost": lost, "error": error}
                    if not late:
                        return {}
                    if interrupt():
                        return {}
                    left = deadline - time.monotonic()
                    if left <= 0:
                        return {"stalled": sorted(late)}
                    # The timeout bounds how long a vehicle fault (interrupt) waits to be noticed.
                    self.cv.wait(min(left, 0.1))
            finally:
                self._awaited = None

    def lost_among(self, robots: list[int]) -> str | None:
        gone = sorted(set(robots) & self.lost)
        if gone:
            return f"robot(s) {gone} lost (liveliness gone)"
        bad = sorted(set(robots) & set(self.errors))
        if bad:
            return f"robot {bad[0]} failed: {self.errors[bad[0]]}"
        return None

    def close(self) -> None:
        self._warn.flush()   # the warnings held back, said now rather than at exit
        for h in self._handles:
            h.close()
