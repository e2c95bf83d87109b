"""The fake UAV of the robot suite: it puts plans, ticks and the mission end, and records what robots answer."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from protocol.errors import ProtocolError, UavRobotsError
from protocol.keys import Keys, ids_of_states_key, robot_id_from_key
from protocol.messages import Done, MissionEnd, Plan, PlanAck, RobotState, StateBatch, Tick
from protocol.codec import decode, encode
from protocol.transport import Handle, Transport

from .waiter import Waiter


@dataclass
class FakeUav(Waiter):
    """Sends plans, ticks and the mission end; records every robot's acks, states and done flags."""
    transport: Transport
    keys: Keys
    announce: bool = True
    alive: set[int] = field(default_factory=set)
    acks: dict[int, list[PlanAck]] = field(default_factory=dict)
    states: dict[int, list[RobotState]] = field(default_factory=dict)
    dones: dict[int, list[Done]] = field(default_factory=dict)
    garbage: list[str] = field(default_factory=list)
    batches: list[tuple[str, int]] = field(default_factory=list)   # (key, tick) of each StateBatch
    batch_seqs: list[int] = field(default_factory=list)              # seq of each StateBatch

    def __post_init__(self) -> None:
        Waiter.__init__(self)
        self.seq = 0
        t, k = self.transport, self.keys
        self._handles: list[Handle] = [
            t.subscribe(k.all_acks, self._collect(PlanAck, self.acks)),
            t.subscribe(k.all_states, self._collect(RobotState, self.states)),
            t.subscribe(k.all_done, self._collect(Done, self.dones)),
            t.subscribe(k.all_state_batches, self._on_batch),
            t.watch_alive(k.alive_robots, self._on_alive),
        ]
        self._token = t.announce(k.alive_uav) if self.announce else None

    def _collect(self, cls: type, into: dict[int, list[Any]]) -> Callable[[str, bytes], None]:
        def cb(key: str, payload: bytes) -> None:
            try:
                msg = decode(payload, cls)
            except ProtocolError as exc:
                self.garbage.append(f"{key}: {exc}")
                self.changed()
                return
            rid = robot_id_from_key(key)
            if msg.robot != rid:
                self.garbage.append(f"{key}: message for robot {msg.robot}")
            with self.cv:
                into.setdefault(rid, []).append(msg)
                self.cv.notify_all()
        return cb

    def _on_batch(self, key: str, payload: bytes) -> None:
        """A pool's StateBatch: each entry a RobotState of the batch's tick, for the robots its key names only
        (docs/protocol.md, State batches)."""
        try:
            ids = set(ids_of_states_key(self.keys, key))
            batch = decode(payload, StateBatch)
        except (ProtocolError, UavRobotsError) as exc:
            self.garbage.append(f"{key}: {exc}")
            self.changed()
            return
        with self.cv:
            self.batches.append((key, batch.tick))
            self.batch_seqs.append(batch.seq)
            for robot, cell, status, plan_id, error in batch.states:
                if robot not in ids:
                    self.garbage.append(f"{key}: a state of robot {robot}, which the key does not name")
                    continue
                self.states.setdefault(robot, []).append(RobotState(robot=robot, tick=batch.tick, cell=cell,
                                                                    status=status, plan_id=plan_id, error=error))
            self.cv.notify_all()

    def _on_alive(self, key: str, alive: bool) -> None:
        rid = robot_id_from_key(key)
        with self.cv:
            if rid is not None:
                (self.alive.add if alive else self.alive.discard)(rid)
            self.cv.notify_all()

    def _next(self) -> int:
        self.seq += 1
        return self.seq

    def plan(self, robot: int, plan_id: str, path: list[tuple[int, int]], goal: tuple[int, int] | None = None,
             for_robot: int | None = None, start_tick: int = 0, connectivity: int = 0) -> None:
        msg = Plan(robot=robot if for_robot is None else for_robot, plan_id=plan_id, path=list(path),
                   goal=goal if goal is not None else path[-1], start_tick=start_tick, connectivity=connectivity,
                   seq=self._next())
        self.transport.put(self.keys.plan(robot), encode(msg))

    def tick(self, k: int, ticks: int, plan_id: str, batch_states: bool = False) -> None:
        self.transport.put(self.keys.tick, encode(Tick(k=k, ticks=ticks, plan_id=plan_id, batch_states=batch_states,
                                                       seq=self._next())))

    def end(self, completed: bool = True, reason: str = "") -> None:
        self.transport.put(self.keys.mission_end, encode(MissionEnd(completed=completed, reason=reason,
                                                                    seq=self._next())))

    def leave(self) -> None:
        """Withdraw the UAV's liveliness token, as a crashed UAV would."""
        if self._token is not None:
            self._token.close()
            self._token = None

    def ack_for(self, robot: int, plan_id: str, timeout: float) -> PlanAck | None:
        def found() -> bool:
            return any(a.plan_id == plan_id for a in self.acks.get(robot, []))
        if not self.until(found, timeout):
            return None
        return next(a for a in self.acks[robot] if a.plan_id == plan_id)

    def acks_for(self, robot: int, plan_id: str, count: int, timeout: float) -> list[PlanAck]:
        """The first `count` acks for `plan_id` (fewer if they do not come within `timeout`)."""
        def of() -> list[PlanAck]:
            return [a for a in self.acks.get(robot, []) if a.plan_id == plan_id]
        self.until(lambda: len(of()) >= count, timeout)
        with self.cv:
            return of()[:count]

    def state_at(self, robot: int, k: int, timeout: float) -> RobotState | None:
        def found() -> bool:
            return any(s.tick == k for s in self.states.get(robot, []))
        if not self.until(found, timeout):
            return None
        return next(s for s in self.states[robot] if s.tick == k)

    def close(self) -> None:
        self.leave()
        for h in self._handles:
            h.close()
