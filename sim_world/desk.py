"""The move desk: one tick's moves collected from every robot, then judged together.

Queried moves (`world/move`, one robot's MoveRequest or a pool's MoveBatch) come here
directly; moves put ahead come through sim_world/ahead.py once their Tick is heard.
"""
from __future__ import annotations

import sys
import threading
import time
from typing import Callable, NamedTuple

from protocol.grid import Cell
from protocol.messages import MoveRequest, MoveResult

from .config import MOVE_BATCH_TIMEOUT_S
from .moves import MoveJudge

Reply = Callable[[MoveResult], None]


class Ask(NamedTuple):
    """One robot's move of one tick, as the desk keeps it (a MoveRequest, or one move of a MoveBatch)."""
    robot: int
    tick: int
    frm: Cell
    to: Cell


# A move may name a tick at most this many ahead of the world's (the last judged, or the UAV's last
# Tick): a robot asks for the Tick it holds and puts its move one tick early, so anything farther is
# a mistake or a forgery, and it must neither move the world's clock nor grow its memory.
MAX_TICKS_AHEAD = 4


class MoveDesk:
    """Collects one tick's move requests and has them judged together.

    A batch is resolved when every robot has asked, when a request for a later
    tick shows the fleet has moved on, or when the batch timeout expires (the
    robots that did not ask stay and are reported as missing). Answers are sent
    outside the lock: a reply may take the transport's time.
    """

    def __init__(self, judge: MoveJudge, batch_timeout_s: float = MOVE_BATCH_TIMEOUT_S,
                 warn: Callable[[str], None] | None = None) -> None:
        self.judge = judge
        self.warn = warn or (lambda _line: None)
        self.seen = 0                                         # the UAV's last Tick, as the world heard it
        # Robots whose liveliness token is gone (killed, frozen past the lease) are not waited for:
        # a lost robot must not make every later tick wait out the batch timeout.
        self.gone: set[int] = set()
        # Robots that did not ask in the last resolved tick (stalled, or never moving) are not waited
        # for either, until they ask again: one silent robot costs one batch timeout, not one per tick.
        self.quiet: set[int] = set()
        self.batch_timeout_s = batch_timeout_s
        self.cv = threading.Condition()
        self.tick: int | None = None                          # the tick being collected
        self.batch: dict[int, tuple[Ask, Reply]] = {}
        self.waiting: set[int] = set()                        # robots of this tick that have not asked yet
        self.deadline = 0.0
        self.last: dict[int, tuple[Ask, MoveResult]] = {}
        self._closed = False
        self._timer = threading.Thread(target=self._expire_loop, name="move-batches", daemon=True)
        self._timer.start()

    def submit(self, req: MoveRequest, reply: Reply) -> None:
        self.submit_many([(Ask(req.robot, req.tick, req.frm, req.to), reply)])

    def submit_many(self, asks: list[tuple[Ask, Reply]]) -> None:
        """Requests that arrived together (a pool's MoveBatch): judged under one lock, answered after it."""
        sends: list[tuple[Reply, MoveResult]] = []
        with self.cv:
            for req, reply in asks:
                self._take(req, reply, sends)
        send_all(sends)

    def _take(self, req: Ask, reply: Reply, sends: list[tuple[Reply, MoveResult]]) -> None:
        j = self.judge
        if req.robot not in j.positions:
            sends.append((reply, j.slip(req.tick, req.robot, req.frm, req.to, f"unknown robot {req.robot}")))
        elif req.tick <= j.tick or (self.tick is not None and req.tick < self.tick):
            self._heard_late(req.robot)
            prev = self.last.get(req.robot)
            if prev and prev[0].tick == req.tick and (prev[0].frm, prev[0].to) == (req.frm, req.to):
                sends.append((reply, prev[1]))  # a resent request: the same answer again
            else:
                now = self.tick if self.tick is not None else j.tick
                sends.append((reply, j.slip(req.tick, req.robot, req.frm, req.to,
                                            f"tick {req.tick} is over (the world is at tick {now})")))
        elif req.tick > max(j.tick, self.tick or 0, self.seen) + MAX_TICKS_AHEAD:
            # Not recorded as a refusal of the mission: no tick of it was asked.
            why = f"tick {req.tick} is too far ahead (the world is at tick {max(j.tick, self.seen)})"
            self.warn(f"refused robot {req.robot}'s move: {why}")
            sends.append((reply, MoveResult(req.robot, req.tick, False, j.positions[req.robot], why)))
        else:
            if self.tick is not None and req.tick > self.tick:
                sends += self._resolve(f"no move request before tick {req.tick} began: stayed")
            if self.tick is None:
                self.tick = req.tick
                self.deadline = time.monotonic() + self.batch_timeout_s
                # Who must still ask, kept as a set: checking every robot on every request made a
                # tick of N robots cost N^2.
                self.waiting = set(j.positions) - self.gone - self.quiet
                self.cv.notify_all()
            old = self.batch.get(req.robot)
            if old is not None:
                sends.append((old[1], MoveResult(robot=req.robot, tick=req.tick, accepted=False,
                                                 cell=j.positions[req.robot],
                                                 reason="superseded by a newer request")))
            self.batch[req.robot] = (req, reply)
            self.waiting.discard(req.robot)
            if not self.waiting:
                sends += self._resolve("")  # nobody is missing

    def _heard_late(self, robot: int) -> None:
        """A quiet robot asking for a tick already judged is back, one tick behind: from the tick
        being collected on, it is waited for again. Left quiet, it was judged before its query
        came, every tick, and refused "tick k is over" for ever (a stalled robot never rejoined)."""
        if robot in self.quiet:
            self.quiet.discard(robot)
            if self.tick is not None and robot not in self.batch and robot not in self.gone:
                self.waiting.add(robot)

    def robot_alive(self, robot: int, alive: bool) -> list[tuple[Reply, MoveResult]]:
        """Liveliness news; a tick waiting only for a robot that just vanished is resolved now."""
        with self.cv:
            if alive:
                self.gone.discard(robot)
                if self.tick is not None and robot not in self.batch and robot not in self.quiet:
                    self.waiting.add(robot)
                return []
            self.gone.add(robot)
            self.waiting.discard(robot)
            if self.tick is not None and self.batch and not self.waiting:
                return self._resolve(f"robot {robot} vanished: stayed")
            return []

    def _resolve(self, why_missing: str) -> list[tuple[Reply, MoveResult]]:
        tick, batch = self.tick, self.batch
        self.tick, self.batch = None, {}
        assert tick is not None
        outcomes = self.judge.resolve(tick, {r: (q.frm, q.to) for r, (q, _) in batch.items()})
        missing = sorted(set(self.judge.positions) - set(batch))
        self.quiet = set(missing)
        if missing:
            self.judge.note_missing(tick, missing, why_missing)
        out = []
        for r, (q, reply) in batch.items():
            res = outcomes[r]
            self.last[r] = (q, res)
            out.append((reply, res))
        return out

    def _expire_loop(self) -> None:
        while True:
            sends: list[tuple[Reply, MoveResult]] = []
            with self.cv:
                if self._closed:
                    return
                if self.tick is None:
                    self.cv.wait(0.5)
                    continue
                left = self.deadline - time.monotonic()
                if left > 0:
                    self.cv.wait(left)
                    continue
                sends = self._resolve(f"no move request within {self.batch_timeout_s:g} s: stayed")
            send_all(sends)

    def close(self) -> None:
        with self.cv:
            self._closed = True
            self.cv.notify_all()
        self._timer.join(2.0)


def send_all(sends: list[tuple[Reply, MoveResult]]) -> None:
    """The desk's answers, sent once its lock is released: a reply may take the transport's time."""
    for reply, res in sends:
        try:
            reply(res)
        except Exception as exc:  # noqa: BLE001 - one asker gone must not stop the others' answers
            print(f"warning: world: a move reply failed: {exc}", file=sys.stderr, flush=True)
