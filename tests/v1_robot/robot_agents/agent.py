"""The robot process: one robot, or a pool of many robots in one process.

Each hosted robot subscribes to its plan key, the fleet's tick and the mission
end BEFORE it declares its liveliness token, so the UAV, which publishes only
after it sees the token, never sends into the void (NOTES-transports.md,
pitfall 3). Work runs on one worker thread, never inside a Zenoh callback. On a
tick a lone robot sends one MoveRequest; a pool sends all its robots' moves in
one MoveBatch, so a pool of 500 robots costs one query per tick, not 500.

    python -m robot_agents --ids 0-3 --fleet F --connect tcp/127.0.0.1:7447
"""
from __future__ import annotations

import argparse
import queue
import sys
import threading
from typing import Any, Callable, Sequence

from protocol.config import add_session_arguments, session_config
from protocol.errors import ProtocolError, UavRobotsError
from protocol.keys import Keys, robot_id_from_key
from protocol.messages import (MissionEnd, MoveBatch, MoveBatchResult, MoveRequest, MoveResult, Plan, Tick, decode,
                               encode)
from protocol.process import Lifecycle
from protocol.transport import Transport, ZenohTransport

from .robot import RobotMachine, Step

MOVE_TIMEOUT_S = 5.0   # longer than the world's batch timeout, so a slow tick is still answered
JOIN_TIMEOUT_S = 2.0


def _warn(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr, flush=True)


def format_ids(ids: Sequence[int]) -> str:
    """[0, 1, 2, 5] -> '0-2,5' (for log lines)."""
    out: list[str] = []
    ids = sorted(ids)
    i = 0
    while i < len(ids):
        j = i
        while j + 1 < len(ids) and ids[j + 1] == ids[j] + 1:
            j += 1
        out.append(str(ids[i]) if i == j else f"{ids[i]}-{ids[j]}")
        i = j + 1
    return ",".join(out)


def parse_ids(text: str) -> list[int]:
    """'0-3,7,10-11' -> [0, 1, 2, 3, 7, 10, 11]."""
    ids: set[int] = set()
    for part in filter(None, (p.strip() for p in text.split(","))):
        lo, sep, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise UavRobotsError(f"robot ids {text!r}: {part!r} is not a number or a range like 0-49") from None
        if a < 0 or b < a:
            raise UavRobotsError(f"robot ids {text!r}: {part!r} is not a range of non-negative ids")
        ids.update(range(a, b + 1))
    if not ids:
        raise UavRobotsError(f"robot ids {text!r}: no id given")
    return sorted(ids)


class RobotPool(Lifecycle):
    """The robots hosted by one process, wired to a transport."""

    def __init__(self, ids: Sequence[int], transport: Transport, fleet: str, connectivity: int = 4,
                 move_timeout_s: float = MOVE_TIMEOUT_S, stop: threading.Event | None = None) -> None:
        super().__init__(stop)
        if not ids:
            raise UavRobotsError("a robot pool needs at least one robot id")
        if connectivity not in (4, 8):
            raise UavRobotsError(f"connectivity must be 4 or 8, got {connectivity}")
        self.keys = Keys(fleet)
        self.transport = transport
        self.machines = {int(r): RobotMachine(int(r), connectivity) for r in ids}
        self.move_timeout_s = move_timeout_s
        self._seq = {r: 0 for r in self.machines}
        self._batch_seq = 0
        self._work: queue.Queue[tuple[str, Any] | None] = queue.Queue()
        self._uav_seen = False
        self._worker = threading.Thread(target=self._loop, name="robot-pool", daemon=True)
        self.label = format_ids(list(self.machines))

    # ------------------------------------------------------------ wiring
    def start(self) -> None:
        k = self.keys
        if len(self.machines) == 1:
            (r,) = self.machines
            self.keep(self.transport.subscribe(k.plan(r), self._queue_plan(r)))
        else:
            # One wildcard subscription, not one per robot: Zenoh's Python binding runs a thread per callback.
            self.keep(self.transport.subscribe(f"{k.prefix}/robot/*/plan", self._on_any_plan))
        self.keep(self.transport.subscribe(k.tick, lambda _k, p: self._work.put(("tick", p))),
                  self.transport.subscribe(k.mission_end, self._on_end),
                  self.transport.watch_alive(k.alive_uav, self._on_uav))
        self._worker.start()
        # Last: the tokens tell the UAV that everything above is listening.
        for r in self.machines:
            self.keep(self.transport.announce(k.alive_robot(r)))

    def _queue_plan(self, robot: int) -> Callable[[str, bytes], None]:
        return lambda _key, payload: self._work.put(("plan", (robot, payload)))

    def _on_any_plan(self, key: str, payload: bytes) -> None:
        rid = robot_id_from_key(key)
        if rid in self.machines:
            self._work.put(("plan", (rid, payload)))

    def _on_end(self, _key: str, payload: bytes) -> None:
        try:
            end = decode(payload, MissionEnd)
        except ProtocolError as exc:
            _warn(f"robots {self.label}: ignored mission end: {exc}")
            return
        self.finish("mission ended" + (" (completed)" if end.completed else f": {end.reason or 'aborted'}"))

    def _on_uav(self, _key: str, alive: bool) -> None:
        if alive:
            self._uav_seen = True
        elif self._uav_seen:
            self.finish("the UAV went away: mission aborted")

    def close(self) -> None:
        self.stop.set()
        self._work.put(None)
        if self._worker.is_alive() and threading.current_thread() is not self._worker:
            self._worker.join(JOIN_TIMEOUT_S)
        self.release()

    # ------------------------------------------------------------ worker
    def _loop(self) -> None:
        while not self.stop.is_set():
            item = self._work.get()
            if item is None:
                return
            kind, data = item
            try:
                if kind == "plan":
                    self._on_plan(*data)
                else:
                    self._on_tick(data)
            except ProtocolError as exc:
                _warn(f"robots {self.label}: ignored {kind}: {exc}")
            except Exception as exc:  # noqa: BLE001 - the pool must outlive one bad message
                if not self.stop.is_set():
                    _warn(f"robots {self.label}: {kind} failed: {exc}")

    def _put(self, robot: int, key: str, msg: Any) -> None:
        self._seq[robot] += 1
        object.__setattr__(msg, "seq", self._seq[robot])  # the message was made here, for this put only
        self.transport.put(key, encode(msg))

    def _on_plan(self, robot: int, payload: bytes) -> None:
        plan = decode(payload, Plan)
        ack = self.machines[robot].on_plan(plan)
        if not ack.ok:
            _warn(f"robot {robot}: refused plan {plan.plan_id}: {ack.error}")
        self._put(robot, self.keys.ack(robot), ack)

    def _on_tick(self, payload: bytes) -> None:
        tick = decode(payload, Tick)
        if tick.k < 1:
            raise ProtocolError(f"tick {tick.k} is not a positive step number")
        steps: dict[int, Step] = {}
        gaps: list[int] = []
        for r, m in self.machines.items():
            last = m.last_tick
            kind = m.classify(tick)
            if kind == "old":
                continue
            if kind == "gap":
                gaps.append(last)
            step = m.target(tick.k, tick.plan_id)
            if step is not None:
                steps[r] = step
        if gaps:
            _warn(f"robots {self.label}: tick {tick.k} follows tick {min(gaps)}: "
                  f"missed {tick.k - 1 - min(gaps)} tick(s)")
        if not steps:
            return
        results = self._ask_world(tick.k, steps)
        for r, step in steps.items():
            m = self.machines[r]
            result = results.get(r)
            if result is None:
                state = m.on_no_result(step, f"no answer from the world's move service for tick {tick.k}")
                done = None
            else:
                state, done = m.on_move_result(result, tick.plan_id)
            self._put(r, self.keys.state(r), state)
            if done is not None:
                self._put(r, self.keys.done(r), done)

    def _ask_world(self, k: int, steps: dict[int, Step]) -> dict[int, MoveResult]:
        """One MoveRequest for a lone robot; one MoveBatch for a pool: a query costs far more than its size."""
        if len(steps) == 1:
            (r, st), = steps.items()
            self._seq[r] += 1
            req = MoveRequest(robot=r, tick=k, frm=st.frm, to=st.to, seq=self._seq[r])
            res = self._result(r, k, self.transport.request(self.keys.move, encode(req), self.move_timeout_s))
            return {r: res} if res is not None else {}
        self._batch_seq += 1
        batch = MoveBatch(tick=k, moves=[(r, st.frm, st.to) for r, st in steps.items()], seq=self._batch_seq)
        out: dict[int, MoveResult] = {}
        for raw in self.transport.request(self.keys.move, encode(batch), self.move_timeout_s):
            try:
                reply = decode(raw, MoveBatchResult)
            except ProtocolError as exc:
                _warn(f"robots {self.label}: ignored move results: {exc}")
                continue
            if reply.tick != k:
                _warn(f"robots {self.label}: ignored move results for tick {reply.tick}")
                continue
            for robot, accepted, cell, reason in reply.results:
                if robot in steps:
                    out[robot] = MoveResult(robot=robot, tick=k, accepted=accepted, cell=cell, reason=reason)
        return out

    def _result(self, robot: int, tick: int, replies: list[bytes]) -> MoveResult | None:
        for raw in replies:
            try:
                res = decode(raw, MoveResult)
            except ProtocolError as exc:
                _warn(f"robot {robot}: ignored move result: {exc}")
                continue
            if res.robot == robot and res.tick == tick:
                return res
            _warn(f"robot {robot}: ignored move result for robot {res.robot} tick {res.tick}")
        return None


def run_robots(ids: Sequence[int], transport: Transport, fleet: str, connectivity: int = 4,
               move_timeout_s: float = MOVE_TIMEOUT_S, stop: threading.Event | None = None,
               on_ready: Callable[[RobotPool], None] | None = None) -> int:
    """Host `ids` until the mission ends, the UAV goes away, or `stop` is set. Returns 0."""
    pool = RobotPool(ids, transport, fleet, connectivity, move_timeout_s, stop)
    try:
        pool.start()
        if on_ready is not None:
            on_ready(pool)
        pool.serve()
    finally:
        pool.close()
    return 0


# ------------------------------------------------------------------ CLI
def add_robot_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("robot", help="run one robot, or a pool of robots, on a fleet",
                              description="Run simulated robots that execute plans tick by tick over Zenoh.")
    add_robot_arguments(p)
    p.set_defaults(func=robot_command)
    return p


def add_robot_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--id", dest="id", type=int, action="append", default=[], metavar="K",
                   help="a robot id to host (repeat for several)")
    p.add_argument("--ids", default=None, metavar="RANGES", help="robot ids as ranges, e.g. 0-49 or 0-3,7")
    p.add_argument("--fleet", required=True, help="fleet name: keys live under uavr/<fleet>")
    add_session_arguments(p)
    p.add_argument("--connectivity", type=int, choices=(4, 8), default=4)
    p.add_argument("--move-timeout", type=float, default=MOVE_TIMEOUT_S, metavar="S",
                   help="how long to wait for the world's answer to a move")


def robot_command(args: argparse.Namespace) -> int:
    ids = sorted(set(args.id) | set(parse_ids(args.ids) if args.ids else []))
    if not ids:
        raise UavRobotsError("give the robots to host: --id K (repeatable) or --ids 0-49")
    if any(i < 0 for i in ids):
        raise UavRobotsError("robot ids must be non-negative")
    Keys(args.fleet)  # a bad fleet name fails before the session opens
    conf = session_config(args.listen, args.connect, args.zenoh_config)
    life = Lifecycle()   # signals stop the pool even while the session is still opening
    life.stop_on_signals()
    stop = life.stop
    with ZenohTransport(conf, f"robots {format_ids(ids)}") as transport:
        def ready(pool: RobotPool) -> None:
            noun = "robot" if len(ids) == 1 else "robots"
            print(f"{noun} {pool.label} ready (fleet {args.fleet})", flush=True)

        pools: list[RobotPool] = []
        code = run_robots(ids, transport, args.fleet, args.connectivity, args.move_timeout, stop,
                          lambda pool: (pools.append(pool), ready(pool)))
    reason = pools[0].exit_reason if pools and pools[0].exit_reason else "stopped"
    print(f"robots {format_ids(ids)}: {reason}", flush=True)
    return code

