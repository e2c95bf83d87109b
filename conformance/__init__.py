"""A harness that plays hub, UAV and world around a robot implementation under test.

The conformance suite (`test_robot_conformance.py` beside this file) uses it
to check any robot that speaks the protocol, started from a command line; our
own tests use it to drive the real world and robots. Everything here talks
only through `protocol` (Zenoh on loopback), never through robot internals.
"""
from __future__ import annotations

import json
import os
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from protocol.codec import decode, encode
from protocol.config import hub_config
from protocol.errors import MissionError, ProtocolError, UavRobotsError
from protocol.keys import Keys, ids_of_states_key, new_fleet_name, robot_id_from_key
from protocol.messages import (Done, MissionEnd, MoveAhead, MoveBatch, MoveBatchResult, MoveRequest, MoveResult,
                               MovesJudged, Plan, PlanAck, RobotState, StateBatch, Tick)
from protocol.transport import Handle, IncomingQuery, Transport, ZenohTransport

REPO = Path(__file__).resolve().parents[1]
DEFAULT_ROBOT_CMD = f"{shlex.quote(sys.executable)} -m robot_agents --id {{id}} --fleet {{fleet}} --connect {{endpoint}}"
DEFAULT_POOL_CMD = f"{shlex.quote(sys.executable)} -m robot_agents --ids {{ids}} --fleet {{fleet}} --connect {{endpoint}}"


def free_endpoint() -> str:
    """A loopback TCP endpoint on a port the kernel just had free (bind port 0, then release)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


class Hub:
    """A Zenoh router session on a free loopback port (or on `endpoint`), for one fleet."""

    def __init__(self, fleet: str | None = None, attempts: int = 5, endpoint: str | None = None) -> None:
        self.fleet = fleet or new_fleet_name()
        self.keys = Keys(self.fleet)
        last: Exception | None = None
        for _ in range(1 if endpoint else attempts):
            self.endpoint = endpoint or free_endpoint()
            try:
                self.transport: Transport = ZenohTransport(hub_config([self.endpoint]), "conformance hub")
                return
            except MissionError as exc:  # the port was taken between probe and bind: try another
                last = exc
        raise MissionError(f"no free port for a Zenoh router after {attempts} attempts: {last}")

    def close(self) -> None:
        self.transport.close()

    def __enter__(self) -> "Hub":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Waiter:
    """A condition variable with `until(predicate, timeout)`, shared by the fakes."""

    def __init__(self) -> None:
        self.cv = threading.Condition()

    def changed(self) -> None:
        with self.cv:
            self.cv.notify_all()

    def until(self, pred: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self.cv:
            while not pred():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.cv.wait(min(left, 0.2))
            return True


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


class Wire(Waiter):
    """Every put of the robot(s) under test as the router got it: (key, payload, congestion control), in order.

    Read from the router's own session, below `protocol.transport`: the congestion control a put was
    sent with travels with it (docs/protocol.md, QoS) and only a Zenoh sample shows it.
    """
    SUFFIXES = ("/ack", "/state", "/done", "/states")

    def __init__(self, hub: "Hub") -> None:
        super().__init__()
        self.puts: list[tuple[str, bytes, str]] = []
        self._ahead = f"{hub.keys.prefix}/world/ahead/"
        self._sub = hub.transport.session.declare_subscriber(f"{hub.keys.prefix}/**", self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        if key.endswith(self.SUFFIXES) or key.startswith(self._ahead):
            with self.cv:
                self.puts.append((key, sample.payload.to_bytes(), str(sample.congestion_control).rsplit(".", 1)[-1]))
                self.cv.notify_all()

    def order(self) -> list[tuple[str, int]]:
        """(key, tick or -1) of each put, in the order the router got them."""
        out = []
        with self.cv:
            for key, payload, _cc in self.puts:
                try:
                    tick = json.loads(payload).get("tick", -1)
                except (ValueError, AttributeError):
                    tick = -1
                out.append((key, tick if isinstance(tick, int) else -1))
        return out

    def count(self, key: str, tick: int = -1) -> int:
        """How many puts on `key` (naming `tick`, -1 for any) the router got."""
        return sum(1 for item in self.order() if item[0] == key and (tick == -1 or item[1] == tick))

    def close(self) -> None:
        self._sub.undeclare()


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


def robot_command(template: str, robot: int | list[int], fleet: str, endpoint: str) -> list[str]:
    """The command line from a template: {id} for one robot; {ids} (comma-separated) for a pool."""
    ids = robot if isinstance(robot, list) else [robot]
    try:
        text = template.format(id=ids[0], ids=",".join(map(str, ids)), fleet=fleet, endpoint=endpoint)
    except (KeyError, IndexError, ValueError) as exc:
        raise MissionError(f"robot command {template!r}: bad placeholder {exc}; use {{id}} (or {{ids}} for a pool) "
                           "{fleet} {endpoint}") from None
    return shlex.split(text)


def start_robot(template: str, robot: int | list[int], fleet: str, endpoint: str,
                log: Path | None = None) -> subprocess.Popen:
    argv = robot_command(template, robot, fleet, endpoint)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH", "")]))
    out = open(log, "wb") if log is not None else subprocess.DEVNULL
    try:
        # A new session: the robot and any children it starts can be killed as one group.
        return subprocess.Popen(argv, cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    finally:
        if log is not None:
            out.close()


def stop_process(proc: subprocess.Popen, grace: float = 3.0) -> int | None:
    """SIGTERM the process group, then SIGKILL it; returns the exit code (None if it had to be killed)."""
    if proc.poll() is None:
        signal_group(proc, signal.SIGTERM)
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            signal_group(proc, signal.SIGKILL)
            proc.wait(5)
            return None
    return proc.returncode


def signal_group(proc: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass
