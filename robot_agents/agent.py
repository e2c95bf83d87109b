"""The robot process: one robot, or a pool of many robots in one process.

Each hosted robot subscribes to its plan key, the fleet's tick and the mission
end BEFORE it declares its liveliness token, so the UAV, which publishes only
after it sees the token, never sends into the void (NOTES-transports.md,
pitfall 3). Work runs on one worker thread, never inside a Zenoh callback (but for
the world's answers to moves put ahead, below, which only lead to puts). On a
tick a lone robot sends one MoveRequest; a pool sends all its robots' moves in
one MoveBatch, so a pool of 500 robots costs one query per tick, not 500.

With `--moves ahead` the robots wake once a tick, not twice: on the world's MovesJudged for
tick k they put their moves for k+1 (one MoveAhead), then their states of k; the world judges
those moves when the UAV's Tick(k+1) comes (docs/protocol.md, "Moving ahead"). A process
with injected faults keeps the query mode: its faults are timed by the Tick it then reads.

    python -m robot_agents --ids 0-3 --fleet F --connect tcp/127.0.0.1:7447
"""
from __future__ import annotations

import argparse
import os
import queue
import sys
import threading
from typing import Any, Callable, Sequence

from protocol.codec import decode, encode
from protocol.config import add_session_arguments
from protocol.errors import ProtocolError, UavRobotsError
from protocol.faults import ROBOTS, Fault, parse_fault, usage
from protocol.keys import DEFAULT_FLEET, Keys, format_ids, parse_ids, robot_id_from_key  # noqa: F401 - re-exported
from protocol.log import Throttled
from protocol.messages import (Done, MissionEnd, MoveAhead, MoveBatch, MoveBatchResult, MoveRequest, MoveResult,
                               MovesJudged, Plan, RobotState, StateBatch, Tick)
from protocol.process import Lifecycle, command_main, one_command
from protocol.run_spec import add_spec_argument, apply_spec
from protocol.transport import Transport, lean_runtime, open_session

from .robot import RobotMachine, Step

MOVE_TIMEOUT_S = 5.0   # longer than the world's batch timeout, so a slow tick is still answered
JOIN_TIMEOUT_S = 2.0


def _warn(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr, flush=True)


class RobotPool(Lifecycle):
    """The robots hosted by one process, wired to a transport."""

    def __init__(self, ids: Sequence[int], transport: Transport, fleet: str, connectivity: int = 4,
                 move_timeout_s: float = MOVE_TIMEOUT_S, stop: threading.Event | None = None,
                 faults: Sequence[Fault] = (), ahead: bool = False) -> None:
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
        self._states_seq = 0
        self._work: queue.Queue[tuple[str, Any] | None] = queue.Queue()
        self._uav_seen = False
        self._worker = threading.Thread(target=self._loop, name="robot-pool", daemon=True)
        self.label = format_ids(list(self.machines))
        # The key names who asks: under access control only this identity may ask there (docs/protocol.md, Security).
        self.move_key = self.keys.move_as(list(self.machines))
        self.states_key = self.keys.states_as(list(self.machines))
        self.dropped = Throttled(f"robots {self.label}")   # undecodable or foreign messages: counted, rarely said
        self.faults = {f.robot: f for f in faults if f.robot in self.machines}
        self.dead: set[int] = set()
        self._tokens: dict[int, Any] = {}
        self.ahead = ahead and not self.faults
        self.ahead_key = self.keys.ahead_as(list(self.machines))
        self._ahead_seq = 0
        self._mutex = threading.Lock()   # the machines: the worker's plans and the transport's answers

    # ------------------------------------------------------------ wiring
    def start(self) -> None:
        k = self.keys
        if len(self.machines) == 1:
            (r,) = self.machines
            self.keep(self.transport.subscribe(k.plan(r), self._queue_plan(r)))
        else:
            # One wildcard subscription, not one per robot: Zenoh's Python binding runs a thread per callback.
            self.keep(self.transport.subscribe(f"{k.prefix}/robot/*/plan", self._on_any_plan))
        if self.ahead:
            # The world's answers, not the Tick, pace a robot that moves ahead: one wake a tick, taken
            # on the transport's thread (it only puts, never waits), not handed to the worker: the
            # hand-over cost about as much as the rest of the tick.
            self.keep(self.transport.subscribe(k.judged_as(list(self.machines)),
                                               lambda _k, p: self._handle("judged", p), inline=True))
        else:
            self.keep(self.transport.subscribe(k.tick, lambda _k, p: self._work.put(("tick", p)), inline=True))
        self.keep(self.transport.subscribe(k.mission_end, self._on_end),
                  self.transport.watch_alive(k.alive_uav, self._on_uav))
        self._worker.start()
        # Last: the tokens tell the UAV that everything above is listening.
        for r in self.machines:
            self._tokens[r] = self.transport.announce(k.alive_robot(r))
            self.keep(self._tokens[r])

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
            self.dropped(f"ignored mission end: {exc}")
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
        self.dropped.flush()   # the warnings held back, said now rather than at exit
        self.release()

    # ------------------------------------------------------------ worker
    def _loop(self) -> None:
        while not self.stop.is_set():
            item = self._work.get()
            if item is None:
                return
            self._handle(*item)

    def _handle(self, kind: str, data: Any) -> None:
        with self._mutex:
            try:
                if kind == "plan":
                    self._on_plan(*data)
                elif kind == "judged":
                    self._on_judged(data)
                else:
                    self._on_tick(data)
            except ProtocolError as exc:
                self.dropped(f"ignored {kind}: {exc}")
            except Exception as exc:  # noqa: BLE001 - the pool must outlive one bad message
                if not self.stop.is_set():
                    _warn(f"robots {self.label}: {kind} failed: {exc}")

    def _put(self, robot: int, key: str, msg: Any) -> None:
        self._seq[robot] += 1
        object.__setattr__(msg, "seq", self._seq[robot])  # the message was made here, for this put only
        self.transport.put(key, encode(msg))

    def _on_plan(self, robot: int, payload: bytes) -> None:
        if robot in self.dead:
            return
        plan = decode(payload, Plan)
        m = self.machines[robot]
        ack = m.on_plan(plan)
        if not ack.ok:
            _warn(f"robot {robot}: refused plan {plan.plan_id}: {ack.error}")
        elif self.ahead:
            # Before the ack: the UAV puts the plan's first tick only after every ack, and the
            # world must hold this move (replacing one sent ahead under the old plan) by then.
            self._put_ahead(max(m.seen_tick, m.base) + 1, [robot])
        self._put(robot, self.keys.ack(robot), ack)
        fault = self.faults.get(robot)
        if ack.ok and fault is not None and fault.kind == "liar":
            _warn(f"robot {robot}: fault {fault}: claims its goal without moving")
            self._put(robot, self.keys.done(robot), Done(robot=robot, tick=m.seen_tick, cell=tuple(plan.goal)))

    def _apply_faults(self, k: int) -> set[int]:
        """The robots that act at tick k; a crash fault due now kills its robot."""
        for r, f in self.faults.items():
            if f.kind == "crash" and k >= f.tick and r not in self.dead:
                _warn(f"robot {r}: fault {f}: dies at tick {k}")
                if len(self.machines) == 1:
                    os._exit(3)   # abruptly, like a real crash: no goodbye, no clean session close
                self.dead.add(r)
                self._tokens[r].close()
        return {r for r in self.machines if r not in self.dead
                and not (r in self.faults and self.faults[r].silent_at(k))}

    def _on_tick(self, payload: bytes) -> None:
        tick = decode(payload, Tick)
        if tick.k < 1:
            raise ProtocolError(f"tick {tick.k} is not a positive step number")
        steps: dict[int, Step] = {}
        gaps: list[int] = []
        acting = self._apply_faults(tick.k) if self.faults else self.machines.keys()
        for r, m in self.machines.items():
            if r not in acting:
                continue
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
        outcomes: list[tuple[RobotState, Done | None]] = []
        for r, step in steps.items():
            m = self.machines[r]
            result = results.get(r)
            if result is None:
                outcomes.append((m.on_no_result(step, f"no answer from the world's move service for tick {tick.k}"),
                                 None))
            else:
                outcomes.append(m.on_move_result(result, tick.plan_id))
        self._publish(tick.k, tick.batch_states, outcomes)

    # ------------------------------------------------------------ moving ahead
    def _put_ahead(self, k: int, robots: Sequence[int]) -> None:
        """The moves of tick k of `robots`, one MoveAhead per plan they hold (usually one)."""
        by_plan: dict[str, list[tuple[int, Any, Any]]] = {}
        for r in robots:
            m = self.machines[r]
            step = m.target(k)
            if step is not None:
                by_plan.setdefault(m.plan.plan_id if m.plan else "", []).append((r, step.frm, step.to))
        for plan_id, moves in by_plan.items():
            self._ahead_seq += 1
            self.transport.put(self.ahead_key, encode(MoveAhead(tick=k, plan_id=plan_id, moves=moves,
                                                                seq=self._ahead_seq)))

    def _on_judged(self, payload: bytes) -> None:
        """The world's answer for tick k: first the moves of k+1 (so the world holds them before the
        UAV can put Tick(k+1)), then the states of k and any Done."""
        judged = decode(payload, MovesJudged, len(self.machines))
        k = judged.tick
        fresh: list[tuple[RobotMachine, MoveResult]] = []
        for robot, accepted, cell, reason in judged.results:
            m = self.machines.get(robot)
            if m is None or robot in self.dead or k <= m.last_tick:
                continue   # not ours, or an answer already taken
            fresh.append((m, MoveResult(robot=robot, tick=k, accepted=accepted, cell=cell, reason=reason)))
        if not fresh:
            return
        outcomes = []
        for m, res in fresh:
            m.seen_tick = max(m.seen_tick, k)
            outcomes.append(m.on_move_result(res, judged.plan_id))
        self._put_ahead(k + 1, [m.robot_id for m, _ in fresh])
        self._publish(k, judged.batch_states, outcomes)

    def _publish(self, k: int, batch_states: bool, outcomes: list[tuple[RobotState, Done | None]]) -> None:
        """Each robot's state of tick k, then its Done if any."""
        # A pool answers a UAV that reads StateBatch with one put, not one per robot: at 1,000
        # robots the UAV's decoding of single states was most of a tick.
        batch = batch_states and len(self.machines) > 1
        states: list[RobotState] = []
        for state, done in outcomes:
            if batch:
                states.append(state)
            else:
                self._put(state.robot, self.keys.state(state.robot), state)
            if done is not None:
                self._put(done.robot, self.keys.done(done.robot), done)
        if states:
            self._states_seq += 1
            self.transport.put(self.states_key, encode(StateBatch(
                tick=k, states=[(s.robot, s.cell, s.status, s.plan_id, s.error) for s in states],
                seq=self._states_seq)))

    def _ask_world(self, k: int, steps: dict[int, Step]) -> dict[int, MoveResult]:
        """One MoveRequest for a lone robot; one MoveBatch for a pool: a query costs far more than its size."""
        if len(steps) == 1:
            (r, st), = steps.items()
            self._seq[r] += 1
            req = MoveRequest(robot=r, tick=k, frm=st.frm, to=st.to, seq=self._seq[r])
            res = self._result(r, k, self.transport.request(self.move_key, encode(req), self.move_timeout_s))
            return {r: res} if res is not None else {}
        self._batch_seq += 1
        batch = MoveBatch(tick=k, moves=[(r, st.frm, st.to) for r, st in steps.items()], seq=self._batch_seq)
        out: dict[int, MoveResult] = {}
        for raw in self.transport.request(self.move_key, encode(batch), self.move_timeout_s):
            try:
                reply = decode(raw, MoveBatchResult, len(steps))
            except ProtocolError as exc:
                self.dropped(f"ignored move results: {exc}")
                continue
            if reply.tick != k:
                self.dropped(f"ignored move results for tick {reply.tick}")
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
                self.dropped(f"robot {robot}: ignored move result: {exc}")
                continue
            if res.robot == robot and res.tick == tick:
                return res
            self.dropped(f"robot {robot}: ignored move result for robot {res.robot} tick {res.tick}")
        return None


def run_robots(ids: Sequence[int], transport: Transport, fleet: str, connectivity: int = 4,
               move_timeout_s: float = MOVE_TIMEOUT_S, stop: threading.Event | None = None,
               on_ready: Callable[[RobotPool], None] | None = None, faults: Sequence[Fault] = (),
               ahead: bool = False) -> int:
    """Host `ids` until the mission ends, the UAV goes away, or `stop` is set. Returns 0."""
    pool = RobotPool(ids, transport, fleet, connectivity, move_timeout_s, stop, faults, ahead)
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
    p.add_argument("--fleet", default=DEFAULT_FLEET, help=f"fleet name: keys live under uavr/<fleet> (default {DEFAULT_FLEET})")
    add_session_arguments(p)
    p.add_argument("--connectivity", type=int, choices=(4, 8), default=4)
    p.add_argument("--move-timeout", type=float, default=MOVE_TIMEOUT_S, metavar="S",
                   help="how long to wait for the world's answer to a move")
    p.add_argument("--moves", choices=("query", "ahead"), default="query",
                   help="query: ask the world on each Tick (two wakes a tick); ahead: put each move one tick "
                        "ahead and be paced by the world's answers (one wake a tick; docs/protocol.md)")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help=f"inject a fault into a hosted robot (repeatable): {usage(ROBOTS)}")
    add_spec_argument(p)


# What a robot process takes from a run's spec (`--spec OUT/run.json`): the robots' faults (each pool
# keeps those of the robots it hosts).
SPEC_FIELDS = {"--connectivity": lambda s: s.planning.connectivity,
               "--fault": lambda s: s.faults_for(ROBOTS)}


def robot_main(argv: list[str] | None = None) -> int:
    """`python -m robot_agents ARGV` (argv None: the process's own arguments)."""
    return command_main(one_command("python -m robot_agents",
                                    "Simulated robots that execute plans tick by tick over Zenoh.",
                                    add_robot_arguments, robot_command), argv)


def robot_command(args: argparse.Namespace) -> int:
    ids = sorted(set(args.id) | set(parse_ids(args.ids) if args.ids else []))
    if not ids:
        raise UavRobotsError("give the robots to host: --id K (repeatable) or --ids 0-49")
    if any(i < 0 for i in ids):
        raise UavRobotsError("robot ids must be non-negative")
    Keys(args.fleet)  # a bad fleet name fails before the session opens
    apply_spec(args, SPEC_FIELDS)
    faults = [parse_fault(f, ROBOTS) for f in args.fault]
    life = Lifecycle()   # signals stop the pool even while the session is still opening
    life.stop_on_signals()
    stop = life.stop
    if len(ids) == 1:
        lean_runtime()
    with open_session(f"robots {format_ids(ids)}", args.listen, args.connect, args.zenoh_config, stop) as transport:
        def ready(pool: RobotPool) -> None:
            noun = "robot" if len(ids) == 1 else "robots"
            print(f"{noun} {pool.label} ready (fleet {args.fleet})", flush=True)

        pools: list[RobotPool] = []
        code = run_robots(ids, transport, args.fleet, args.connectivity, args.move_timeout, stop,
                          lambda pool: (pools.append(pool), ready(pool)), faults, args.moves == "ahead")
    reason = pools[0].exit_reason if pools and pools[0].exit_reason else "stopped"
    print(f"robots {format_ids(ids)}: {reason}", flush=True)
    return code

