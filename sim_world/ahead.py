"""Moves put ahead: a robot's move for tick k, put before Tick(k), judged when the Tick comes.

A robot in query mode wakes twice a tick (the Tick, then the world's answer) and every
move is a query round trip. A robot moving ahead wakes once: on the world's answer for
tick k it reports its state and puts its move for k+1 at once (`MoveAhead`). The world
keeps those moves until it sees `Tick(k+1)` itself, then hands them to the same MoveDesk
that judges queried moves, so both kinds of robots share one judgment, one batch timeout
and the same rules for missing, quiet and vanished robots (docs/protocol.md, "Moving
ahead"). Each sender gets one `MovesJudged` put per tick on its own key.
"""
from __future__ import annotations

import threading
from typing import Callable

from protocol.messages import MoveAhead, MoveResult, MovesJudged, Tick

from .desk import MAX_TICKS_AHEAD, Ask, MoveDesk

Send = Callable[[str, MovesJudged], None]   # (the sender's ids label, the answer)


class AheadDesk:
    def __init__(self, desk: MoveDesk, send: Send) -> None:
        self.desk = desk
        self.send = send
        self.lock = threading.Lock()
        self.pending: dict[int, dict[int, tuple[str, str, Ask]]] = {}   # tick -> robot -> (label, plan_id, ask)
        self.ticks: dict[int, Tick] = {}   # Ticks seen whose moves may still come (late ones)

    def on_move_ahead(self, label: str, msg: MoveAhead) -> str:
        """Keep the moves until their Tick; a move for a tick already begun goes to the desk now.
        Returns why the message was dropped ('' if it was not)."""
        judged = self.desk.judge.tick
        if msg.tick <= judged and msg.tick not in self.ticks:
            late = msg.tick
        elif msg.tick > max(judged, self.desk.seen) + MAX_TICKS_AHEAD:
            return f"moves for tick {msg.tick} are too far ahead (the world is at tick {judged})"
        else:
            late = 0
        with self.lock:
            tick = self.ticks.get(msg.tick)
            if tick is None and not late:
                per_robot = self.pending.setdefault(msg.tick, {})
                for robot, frm, to in msg.moves:   # the last put for a robot and tick wins (a replan)
                    per_robot[robot] = (label, msg.plan_id, Ask(robot, msg.tick, tuple(frm), tuple(to)))
                return ""
        # Tick already seen (or long judged): the desk decides, as for a late query.
        plan = tick.plan_id if tick is not None else msg.plan_id
        asks = [(label, msg.plan_id, Ask(r, msg.tick, tuple(frm), tuple(to))) for r, frm, to in msg.moves]
        self._submit(msg.tick, plan, tick.batch_states if tick is not None else False, asks)
        return ""

    def on_tick(self, tick: Tick) -> None:
        with self.lock:
            if tick.k in self.ticks or tick.k <= self.desk.judge.tick:
                return   # a resent Tick
            seen = self.desk.seen            # the highest Tick heard, shared with the queried moves' desk
            if seen and tick.k > seen + 1:
                # The UAV's ticks come one by one: a jump is lost Ticks, or a Tick that is not the UAV's.
                self.desk.warn(f"Tick {tick.k} follows Tick {seen}: moves put ahead for the ticks between "
                               "are dropped")
            self.ticks[tick.k] = tick
            self.desk.seen = max(seen, tick.k)
            for old in [t for t in self.ticks if t < tick.k - 1]:
                del self.ticks[old]
            for old in [t for t in self.pending if t < tick.k]:
                del self.pending[old]   # moves for a tick that was never put: nothing to answer
            moves = self.pending.pop(tick.k, {})
        with self.desk.cv:
            gone = set(self.desk.gone)
        # A robot that died after putting its move must not move: a querying robot that dies asks nothing.
        moves = {r: m for r, m in moves.items() if r not in gone}
        if moves:
            self._submit(tick.k, tick.plan_id, tick.batch_states, list(moves.values()))

    def _submit(self, k: int, plan_id: str, batch_states: bool, asks: list[tuple[str, str, Ask]]) -> None:
        """Hand a tick's moves to the desk; each sender's answers go out in one put once all are in."""
        groups: dict[str, list[MoveResult]] = {}
        left: dict[str, int] = {}
        lock = threading.Lock()
        for label, _pid, _ask in asks:
            left[label] = left.get(label, 0) + 1
            groups.setdefault(label, [])

        def answerer(label: str) -> Callable[[MoveResult], None]:
            def reply(res: MoveResult) -> None:
                with lock:
                    groups[label].append(res)
                    left[label] -= 1
                    if left[label]:
                        return
                results = [(r.robot, r.accepted, r.cell, r.reason) for r in groups[label]]
                self.send(label, MovesJudged(tick=k, plan_id=plan_id, results=results, batch_states=batch_states))
            return reply

        replies = {label: answerer(label) for label in groups}
        # A move under another plan than the tick's is a stay: the robot missed the plan (as for a query).
        self.desk.submit_many([(a if pid == plan_id else a._replace(to=a.frm), replies[label])
                               for label, pid, a in asks])
