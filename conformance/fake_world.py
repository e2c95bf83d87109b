"""The fake world of the robot suite: a move service (asked, and moving ahead) that can refuse, delay or garble."""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable

from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.messages import MoveAhead, MoveBatch, MoveBatchResult, MoveRequest, MoveResult, MovesJudged, Tick
from protocol.codec import decode, encode
from protocol.transport import IncomingQuery, Transport

from .waiter import Waiter


@dataclass
class FakeWorld(Waiter):
    """A move service that accepts every request unless told to refuse (robot, tick) pairs.

    It trusts a robot's first `frm` as its position, and then keeps its own
    idea of where the robot is, which it reports in every answer. Told so, it answers late
    (`delay_s`), never (`hold`: the query stays open), or changes its answers (`reply_with` for a
    `MoveResult`, `batch_with` for the entries of a `MoveBatchResult`).
    """
    transport: Transport
    keys: Keys
    refuse: set[tuple[int, int]] = field(default_factory=set)
    requests: list[MoveRequest] = field(default_factory=list)
    request_seqs: list[tuple[int, int]] = field(default_factory=list)  # (robot, seq) of each MoveRequest
    batch_seqs: list[int] = field(default_factory=list)     # of each MoveBatch, in arrival order
    positions: dict[int, tuple[int, int]] = field(default_factory=dict)
    answer: bool = True
    garbage: bool = False      # answer with bytes that do not decode
    aheads: list[tuple[str, MoveAhead]] = field(default_factory=list)   # (key, message) of each MoveAhead put
    move_keys: list[tuple[str, list[int]]] = field(default_factory=list)  # (key, robots) of each move query
    queries: list[tuple[str, int, list[int], bytes]] = field(default_factory=list)  # (key, tick, robots, payload)
    delay_s: float = 0.0       # answer each query this long after it came, from another thread
    hold: bool = False         # answer nothing and keep the query open until close()
    reply_with: Callable[[MoveResult], MoveResult] | None = None
    batch_with: Callable[[list[tuple]], list[tuple]] | None = None
    judge_ahead: bool = True   # answer the moves put ahead (MovesJudged) when their Tick comes

    def __post_init__(self) -> None:
        Waiter.__init__(self)
        self._held: list[IncomingQuery] = []
        self._timers: list[threading.Timer] = []
        self._handle = self.transport.serve(self.keys.move, self._on_move)
        self._by_identity = self.transport.serve(self.keys.moves_by_identity, self._on_move)
        # Moving ahead: moves are kept until their Tick, then judged and answered per sender.
        # Inline, so a move and the Tick after it are taken in the order they came.
        self._ahead = self.transport.subscribe(self.keys.all_ahead, self._on_ahead, inline=True)
        self._tick = self.transport.subscribe(self.keys.tick, self._on_tick, inline=True)
        self._token = self.transport.announce(self.keys.alive_world)

    def _on_ahead(self, key: str, payload: bytes) -> None:
        try:
            msg = decode(payload, MoveAhead)
        except ProtocolError:
            return   # the robot's moves are judged by what the robot put: garbage is never answered
        with self.cv:
            self.aheads.append((key, msg))
            self.cv.notify_all()

    def _on_tick(self, _key: str, payload: bytes) -> None:
        try:
            tick = decode(payload, Tick)
        except ProtocolError:
            return   # the suite's own garbage on the tick key
        if not self.judge_ahead:
            return
        with self.cv:
            latest: dict[int, tuple[str, str, tuple, tuple]] = {}
            for key, msg in self.aheads:   # the last put for a robot and tick wins
                if msg.tick == tick.k:
                    for r, frm, to in msg.moves:
                        latest[r] = (key.rsplit("/", 1)[1], msg.plan_id, tuple(frm), tuple(to))
        per_label: dict[str, list[MoveResult]] = {}
        for r, (label, plan_id, frm, to) in latest.items():
            stay = plan_id != tick.plan_id
            per_label.setdefault(label, []).append(
                self._judge(MoveRequest(robot=r, tick=tick.k, frm=frm, to=frm if stay else to)))
        for label, results in per_label.items():
            self.transport.put(f"{self.keys.prefix}/world/judged/{label}", encode(MovesJudged(
                tick=tick.k, plan_id=tick.plan_id, results=[(m.robot, m.accepted, m.cell, m.reason) for m in results],
                batch_states=tick.batch_states)))

    def ahead_for(self, robot: int, tick: int, timeout: float) -> list[tuple[str, MoveAhead]]:
        """The MoveAheads naming `robot` for `tick` (waits up to `timeout` for the first)."""
        def of() -> list[tuple[str, MoveAhead]]:
            return [(k, m) for k, m in self.aheads if m.tick == tick and any(x[0] == robot for x in m.moves)]
        self.until(lambda: bool(of()), timeout)
        with self.cv:
            return of()

    def _on_move(self, q: IncomingQuery) -> None:
        if b'"MoveBatch"' in q.payload[:200]:
            batch = decode(q.payload, MoveBatch)
            with self.cv:
                self.batch_seqs.append(batch.seq)
                self.move_keys.append((q.key, [m[0] for m in batch.moves]))
                self.queries.append((q.key, batch.tick, [m[0] for m in batch.moves], q.payload))
            results = [self._judge(MoveRequest(robot=r, tick=batch.tick, frm=a, to=b)) for r, a, b in batch.moves]
            entries = [(res.robot, res.accepted, res.cell, res.reason) for res in results]
            reply = encode(MoveBatchResult(tick=batch.tick, results=self.batch_with(entries) if self.batch_with
                                           else entries))
        else:
            req = decode(q.payload, MoveRequest)
            with self.cv:
                self.request_seqs.append((req.robot, req.seq))
                self.move_keys.append((q.key, [req.robot]))
                self.queries.append((q.key, req.tick, [req.robot], q.payload))
            res = self._judge(req)
            reply = encode(self.reply_with(res) if self.reply_with else res)
        if self.hold:
            with self.cv:
                self._held.append(q)
            return
        if not self.answer:
            q.finish()
            return

        def send() -> None:
            q.reply(b'{"type":"MoveResult","v":1,"robot":"seven"}' if self.garbage else reply)
        if self.delay_s > 0:
            timer = threading.Timer(self.delay_s, send)
            self._timers.append(timer)
            timer.start()
        else:
            send()

    def _judge(self, req: MoveRequest) -> MoveResult:
        with self.cv:
            self.requests.append(req)
            here = self.positions.setdefault(req.robot, tuple(req.frm))
            ok = (req.robot, req.tick) not in self.refuse
            if ok:
                self.positions[req.robot] = tuple(req.to)
            self.cv.notify_all()
            return MoveResult(robot=req.robot, tick=req.tick, accepted=ok, cell=self.positions[req.robot],
                              reason="" if ok else f"refused by the conformance world (robot stays at {here})")

    def requests_for(self, robot: int, tick: int) -> list[MoveRequest]:
        with self.cv:
            return [r for r in self.requests if r.robot == robot and r.tick == tick]

    def close(self) -> None:
        for timer in self._timers:
            timer.cancel()
        with self.cv:
            held, self._held = self._held, []
        for q in held:
            q.finish()
        self._token.close()
        self._handle.close()
        self._by_identity.close()
        self._ahead.close()
        self._tick.close()
