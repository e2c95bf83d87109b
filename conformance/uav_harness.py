"""A harness that plays router, world and robots around a UAV implementation under test.

The UAV conformance suite (`test_uav_conformance.py` beside this file) starts
the UAV from a command line and surrounds it with: a Zenoh router on a free
loopback port, our real world in this process (ground truth, move service,
camera, and the simulated MAVLink vehicle on a free UDP port), and a fleet of
fake robots that the suite controls. The robots keep the contract of
docs/protocol.md (or break it on purpose), and record everything the UAV sends
them, with the checks that can only be made at the moment a message arrives
(was this robot's token up? had every robot reported the previous tick?).
"""
from __future__ import annotations

import dataclasses
import json
import os
import queue
import shlex
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocol.config import client_config
from protocol.errors import MissionError, ProtocolError
from protocol.grid import Cell, on_grid
from protocol.keys import Keys, robot_id_from_key
from protocol.messages import (Done, Message, MissionEnd, MissionStatus, MoveBatch, MoveBatchResult, Plan, PlanAck,
                               Record, RobotState, Tick, decode, encode)
from protocol.transport import Handle, ZenohTransport

from . import REPO, Hub, Waiter, stop_process

DEFAULT_UAV_CMD = (shlex.quote(sys.executable) + " -m uav_agent --fleet {fleet} --connect {endpoint} "
                   "--mavlink {mavlink} --robots {robots} --tick-timeout {tick_timeout}")
PLACEHOLDERS = "{fleet} {endpoint} {mavlink} {mavlink_port} {robots} {tick_timeout}"
MOVE_TIMEOUT_S = 5.0    # the contract's robot-side move query timeout
SETTLE_S = 2.0          # after the UAV exits: the longest wait for its last messages and token to arrive
ABORT_SLACK_S = 10.0    # beyond the tick timeout, for a failing UAV to say so, end the mission and exit
LATE_JOIN_S = 3.0       # after the UAV's token: when a late robot comes up, unless the UAV dispatches earlier
FIRST_ACK_DELAY_S = 0.5  # the fleet's first ack comes this late, as a real robot's may: a UAV must wait for it


@dataclass(frozen=True)
class UavOptions:
    """What the suite runs: the UAV command line and the site it is given (from conftest's --uav-* options)."""
    cmd: str = DEFAULT_UAV_CMD
    map: str = "warehouse-small"
    robots: int = 3
    seed: int = 0
    time_scale: float = 10.0
    tick_timeout_s: float = 3.0
    mission_timeout_s: float = 90.0
    connectivity: int = 4

    @property
    def abort_s(self) -> float:
        """How long after a robot fails the UAV may take to end the mission and exit non-zero."""
        return self.tick_timeout_s + ABORT_SLACK_S


@dataclass(frozen=True)
class Misbehaviour:
    """What the fake robots do wrong on purpose (robot ids; by default every robot keeps the contract)."""
    refuse: frozenset[int] = frozenset()       # answer the plan with PlanAck(ok=false)
    silent_from: dict[int, int] = field(default_factory=dict)  # robot -> first tick it executes but never reports
    late: frozenset[int] = frozenset()         # declare the liveliness token only when the suite says so
    garbage: frozenset[int] = frozenset()      # also put garbage, wrong-version and forged messages on its keys
    liar: frozenset[int] = frozenset()         # never move, but report every tick as done to plan and raise Done
    deaf: frozenset[int] = frozenset()         # ignore the first plan it receives (as if it was lost on the way)


# ---------------------------------------------------------------- processes
def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def uav_command(template: str, *, fleet: str, endpoint: str, mavlink_port: int, robots: int,
                tick_timeout: float) -> list[str]:
    try:
        text = template.format(fleet=fleet, endpoint=endpoint, mavlink=f"udpin://127.0.0.1:{mavlink_port}",
                               mavlink_port=mavlink_port, robots=robots, tick_timeout=f"{tick_timeout:g}")
    except (KeyError, IndexError, ValueError) as exc:
        raise MissionError(f"--uav-cmd {template!r}: bad placeholder {exc}; use {PLACEHOLDERS}") from None
    return shlex.split(text)


def start_process(argv: list[str], stdout: Path, stderr: Path) -> subprocess.Popen:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH", "")]))
    with open(stdout, "wb") as out, open(stderr, "wb") as err:
        # A new session: the UAV and any children it starts are stopped as one process group.
        return subprocess.Popen(argv, cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                start_new_session=True)


# ---------------------------------------------------------------- the world
class Site:
    """Our world in this process: the floor's truth, the move service, the camera and the MAVLink vehicle."""

    def __init__(self, hub: Hub, opts: UavOptions) -> None:
        from sim_world.world import World, WorldConfig

        self.mavlink_port = free_udp_port()
        self.world = World(WorldConfig(fleet=hub.fleet, map=opts.map, robots=opts.robots, seed=opts.seed,
                                       connectivity=opts.connectivity, time_scale=opts.time_scale,
                                       mavlink=f"udpout:127.0.0.1:{self.mavlink_port}", connect=[hub.endpoint]))
        try:
            self.world.start()
        except BaseException:
            self.world.close()
            raise

    @property
    def truth(self):
        return self.world.truth

    def record(self) -> Record:
        return self.world.record()

    def vehicle(self) -> dict[str, Any] | None:
        return self.world.vehicle_dict()

    def close(self) -> None:
        self.world.close()


# ---------------------------------------------------------------- plans
def step_ok(a: Cell, b: Cell, connectivity: int) -> bool:
    dx, dy = abs(b[0] - a[0]), abs(b[1] - a[1])
    return dx + dy <= 1 if connectivity == 4 else max(dx, dy) <= 1


def plan_problem(plan: Plan, rid: int, cell: Cell, truth: Any, connectivity: int) -> str:
    """Why a robot standing on `cell` must refuse `plan` ('' if it is executable): independent of our planners."""
    h, w = truth.free.shape
    if plan.robot != rid:
        return f"plan on robot {rid}'s key names robot {plan.robot}"
    if not plan.plan_id:
        return "empty plan_id"
    if not plan.path:
        return "empty path"
    if tuple(plan.path[0]) != tuple(cell):
        return f"path starts at {tuple(plan.path[0])}, the robot stands on {tuple(cell)}"
    for i, (x, y) in enumerate(plan.path):
        if not on_grid(x, y, w, h):
            return f"path cell {i} {(x, y)} is off the {w}x{h} grid"
        if not truth.free[y, x]:
            return f"path cell {i} {(x, y)} is an obstacle"
        if i and not step_ok(tuple(plan.path[i - 1]), (x, y), connectivity):
            return f"path step {i} {tuple(plan.path[i - 1])} -> {(x, y)} is not a {connectivity}-connected move"
    if tuple(plan.path[-1]) != tuple(plan.goal):
        return f"path ends at {tuple(plan.path[-1])}, not on its goal {tuple(plan.goal)}"
    if tuple(plan.goal) not in {tuple(g) for g in truth.goals}:
        return f"goal {tuple(plan.goal)} is not a goal marker on the floor"
    return ""


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


# ---------------------------------------------------------------- the fleet
@dataclass
class FakeRobot:
    rid: int
    cell: Cell
    token: Handle | None = None
    plan: Plan | None = None
    base: int = 0                       # plan.path[i] is the cell at tick base + i
    acked: dict[str, bool] = field(default_factory=dict)   # plan_id -> ok
    sent: set[str] = field(default_factory=set)            # plan_ids the UAV sent this robot
    reported: set[int] = field(default_factory=set)        # ticks whose RobotState was put
    done_for: str = ""
    last_state: RobotState | None = None
    seq: int = 0


@dataclass
class Observed:
    """What the UAV sent and what the fleet answered, in arrival order, with monotonic times."""
    plans: list[tuple[float, int, Plan, bool]] = field(default_factory=list)  # time, key's robot, plan, token up
    ticks: list[tuple[float, Tick]] = field(default_factory=list)
    statuses: list[MissionStatus] = field(default_factory=list)
    first_status: float | None = None                                   # when the UAV's first status came
    ends: list[tuple[float, MissionEnd]] = field(default_factory=list)
    uav_alive: list[tuple[float, bool]] = field(default_factory=list)
    seqs: list[tuple[str, int]] = field(default_factory=list)          # (kind, seq) of every UAV message
    acks: list[tuple[float, PlanAck]] = field(default_factory=list)
    dones: list[tuple[float, Done]] = field(default_factory=list)
    joined: dict[int, float] = field(default_factory=dict)              # robot -> when its token went up
    violations: list[tuple[str, str]] = field(default_factory=list)    # (kind, text): the UAV broke the contract
    harness: list[str] = field(default_factory=list)                    # the suite's own trouble (world silent)

    def of(self, *kinds: str) -> list[str]:
        return [text for kind, text in self.violations if kind in kinds]

    def __repr__(self) -> str:  # short: pytest prints it in every failed assertion that mentions it
        return (f"Observed({len(self.plans)} plans, {len(self.ticks)} ticks, {len(self.ends)} ends, "
                f"{len(self.acks)} acks, {len(self.dones)} dones, {len(self.violations)} violations)")


class FakeFleet(Waiter):
    """Robots in this process, on one client session: they answer as the contract says and watch the UAV."""

    def __init__(self, endpoint: str, keys: Keys, truth: Any, behaviour: Misbehaviour, connectivity: int = 4) -> None:
        Waiter.__init__(self)
        self.keys, self.truth, self.behaviour, self.connectivity = keys, truth, behaviour, connectivity
        self.robots = {rid: FakeRobot(rid, tuple(cell)) for rid, cell in sorted(truth.starts.items())}
        self.log = Observed()
        self.seen_tick = 0     # the highest tick the worker has executed
        self._jobs: queue.Queue = queue.Queue()
        self.transport = ZenohTransport(client_config([endpoint]), "conformance robots")
        try:
            t, k = self.transport, keys
            # Subscriptions first, tokens last: in-band readiness, as a real robot does it.
            self._handles = [
                t.subscribe(f"{k.prefix}/robot/*/plan", self._on_plan),
                t.subscribe(k.tick, self._on_tick),
                t.subscribe(k.mission_end, self._on_end),
                t.subscribe(k.mission_status, self._on_status),
                t.watch_alive(k.alive_uav, self._on_uav),
            ]
            self._worker = threading.Thread(target=self._work, name="conformance-robots", daemon=True)
            self._worker.start()
            for rid in self.robots:
                if rid not in behaviour.late:
                    self.join(rid)
        except BaseException:
            self.transport.close()
            raise

    # ------------------------------------------------------------ control
    def join(self, rid: int) -> None:
        """Declare robot `rid`'s liveliness token (a late robot comes up)."""
        with self.cv:
            robot = self.robots[rid]
            if robot.token is None:
                robot.token = self.transport.announce(self.keys.alive_robot(rid))
                self.log.joined[rid] = time.monotonic()
            self.cv.notify_all()

    def dispatching(self) -> bool:
        """The UAV has said it is about to send plans (status phase), or has sent one."""
        with self.cv:
            return bool(self.log.plans) or any(s.phase == "dispatch" for s in self.log.statuses)

    def close(self) -> None:
        self._jobs.put(None)
        self._worker.join(MOVE_TIMEOUT_S + 1)
        for h in self._handles:
            h.close()
        with self.cv:
            for robot in self.robots.values():
                if robot.token is not None:
                    robot.token.close()
                    robot.token = None
        self.transport.close()

    # ------------------------------------------------------------ arrivals (transport threads)
    def _violation(self, kind: str, text: str) -> None:
        with self.cv:
            self.log.violations.append((kind, text))
            self.cv.notify_all()

    def _decode(self, key: str, payload: bytes, cls: type) -> Any:
        try:
            msg = decode(payload, cls)
        except ProtocolError as exc:
            self._violation("malformed", f"the UAV put an unreadable message on {key}: {exc}")
            return None
        with self.cv:
            self.log.seqs.append((cls.__name__, msg.seq))
        return msg

    def _on_plan(self, key: str, payload: bytes) -> None:
        plan = self._decode(key, payload, Plan)
        rid = robot_id_from_key(key)
        if plan is None:
            return
        with self.cv:
            robot = self.robots.get(rid) if rid is not None else None
            up = robot is not None and robot.token is not None
            self.log.plans.append((time.monotonic(), rid if rid is not None else -1, plan, up))
            if robot is not None:
                robot.sent.add(plan.plan_id)
            self.cv.notify_all()
        if robot is None:
            self._violation("plan-unknown", f"plan {plan.plan_id} on {key}: no such robot in the world")
        elif not up:
            # A real robot is not listening yet: the plan is lost.
            self._violation("plan-before-token", f"plan {plan.plan_id} sent to robot {rid} before its token was up")
        elif rid in self.behaviour.deaf and self._first_plan(rid):
            return  # the first plan to reach it is lost: the UAV must put it again
        else:
            self._jobs.put(("plan", rid, plan))

    def _first_plan(self, rid: int) -> bool:
        with self.cv:
            return sum(1 for _, r, _, up in self.log.plans if r == rid and up) == 1

    def _on_tick(self, key: str, payload: bytes) -> None:
        tick = self._decode(key, payload, Tick)
        if tick is None:
            return
        with self.cv:
            prev = self.log.ticks[-1][1].k if self.log.ticks else 0
            prev_plan = self.log.ticks[-1][1].plan_id if self.log.ticks else None
            self.log.ticks.append((time.monotonic(), tick))
            problems = []
            if tick.k != prev + 1:
                problems.append(("tick-order", f"Tick {tick.k} followed Tick {prev}"))
            if tick.plan_id != prev_plan:
                # The first tick of a plan: every robot it was sent to has taken it (a replan leaves out
                # the robots the UAV gave up on; they get no plan and stay).
                unacked = [r.rid for r in self.robots.values()
                           if (prev == 0 or tick.plan_id in r.sent) and not r.acked.get(tick.plan_id)]
                if unacked:
                    problems.append(("tick-before-ack", f"Tick {tick.k} (plan {tick.plan_id}) before robots "
                                                        f"{unacked} acknowledged that plan"))
            else:
                silent = [r.rid for r in self.robots.values() if r.acked.get(tick.plan_id) and prev not in r.reported]
                if silent:
                    problems.append(("barrier", f"Tick {tick.k} before robots {silent} reported tick {prev}"))
            if self.log.ends:
                problems.append(("after-end", f"Tick {tick.k} after MissionEnd"))
            self.log.violations += problems
            self.cv.notify_all()
        self._jobs.put(("tick", tick))

    def _on_end(self, key: str, payload: bytes) -> None:
        end = self._decode(key, payload, MissionEnd)
        if end is not None:
            with self.cv:
                self.log.ends.append((time.monotonic(), end))
                self.cv.notify_all()
            self._jobs.put(("end",))

    def _on_status(self, key: str, payload: bytes) -> None:
        status = self._decode(key, payload, MissionStatus)
        if status is not None:
            with self.cv:
                self.log.statuses.append(status)
                if self.log.first_status is None:
                    self.log.first_status = time.monotonic()
                self.cv.notify_all()

    def _on_uav(self, _key: str, alive: bool) -> None:
        with self.cv:
            self.log.uav_alive.append((time.monotonic(), alive))
            self.cv.notify_all()

    # ------------------------------------------------------------ the robots' work (one thread, in order)
    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            try:
                if job[0] == "plan":
                    self._plan(job[1], job[2])
                elif job[0] == "tick":
                    self._tick(job[1])
                else:
                    self._end()
            except Exception as exc:  # noqa: BLE001 - the suite reports it; the fleet keeps answering
                with self.cv:
                    self.log.harness.append(f"{job[0]}: {type(exc).__name__}: {exc}")
                    self.cv.notify_all()

    def _put(self, robot: FakeRobot, key: str, msg: Message) -> None:
        robot.seq += 1
        self.transport.put(key, encode(dataclasses.replace(msg, seq=robot.seq)))

    def _other(self, rid: int) -> int | None:
        others = [r for r in self.robots if r != rid]
        return others[0] if others else None

    def _plan(self, rid: int, plan: Plan) -> None:
        robot = self.robots[rid]
        with self.cv:
            held = robot.plan
        if held is not None and held.plan_id == plan.plan_id:
            same = plan.path == held.path and tuple(plan.goal) == tuple(held.goal)
            problem = "" if same else f"plan {plan.plan_id} was resent with another path"
        else:
            problem = plan_problem(plan, rid, robot.cell, self.truth, self.connectivity)
        if problem:
            self._violation("bad-plan", f"robot {rid}, plan {plan.plan_id}: {problem}")
        ok = not problem and rid not in self.behaviour.refuse
        error = problem or ("" if ok else "refused on purpose by the conformance suite")
        if rid in self.behaviour.garbage:
            other = self._other(rid)
            fake = PlanAck(robot=rid, plan_id=plan.plan_id, ok=False, error="must be dropped")
            for payload in junk(fake, dataclasses.replace(fake, robot=other) if other is not None else None):
                self.transport.put(self.keys.ack(rid), payload)
        ack = PlanAck(robot=rid, plan_id=plan.plan_id, ok=ok, error=error)
        if not self.log.acks:
            time.sleep(FIRST_ACK_DELAY_S)
        with self.cv:
            if ok and (held is None or held.plan_id != plan.plan_id):
                robot.plan, robot.base, robot.done_for = plan, plan.start_tick or self.seen_tick, ""
            robot.acked[plan.plan_id] = ok
            self.log.acks.append((time.monotonic(), ack))
        self._put(robot, self.keys.ack(rid), ack)

    def _target(self, robot: FakeRobot, tick: Tick) -> Cell:
        plan = robot.plan
        if plan is None or plan.plan_id != tick.plan_id:
            if plan is not None and tick.plan_id in robot.sent:
                self._violation("tick-plan-id", f"Tick {tick.k} names plan {tick.plan_id}, robot {robot.rid} "
                                                f"holds {plan.plan_id}")
            return robot.cell  # the contract: a tick for another plan (or none) means stay
        i = tick.k - robot.base
        return tuple(plan.path[max(0, min(i, len(plan.path) - 1))])

    def _tick(self, tick: Tick) -> None:
        if tick.k <= self.seen_tick:
            return  # a resent or late tick: already executed
        with self.cv:
            moves = [(r.rid, r.cell, self._target(r, tick)) for r in self.robots.values()
                     if r.rid not in self.behaviour.liar]
        # All robots' moves in one query: the world judges a tick once every robot has asked.
        replies = self.transport.request(self.keys.move, encode(MoveBatch(tick=tick.k, moves=moves)), MOVE_TIMEOUT_S)
        if not replies:
            raise MissionError(f"the world did not answer the moves of tick {tick.k}")
        result = decode(replies[0], MoveBatchResult)
        self.seen_tick = tick.k
        for rid in self.behaviour.liar & set(self.robots):
            self._lie(self.robots[rid], tick)
        for rid, accepted, cell, reason in result.results:
            robot = self.robots[rid]
            with self.cv:
                robot.cell = tuple(cell)
            if tick.k >= self.behaviour.silent_from.get(rid, tick.k + 1):
                continue  # executes the tick but stops reporting: the UAV's barrier must hold
            self._report(robot, tick, accepted, reason)

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

    def _report(self, robot: FakeRobot, tick: Tick, accepted: bool, reason: str) -> None:
        plan, rid, k = robot.plan, robot.rid, tick.k
        arrived = (plan is not None and plan.plan_id == tick.plan_id and k - robot.base >= len(plan.path) - 1
                   and robot.cell == tuple(plan.goal))
        state = RobotState(robot=rid, tick=k, cell=robot.cell, status="done" if arrived else "stepping",
                           plan_id=plan.plan_id if plan else "", error="" if accepted else reason)
        garbage = rid in self.behaviour.garbage and k <= 3
        other = self._other(rid)
        if garbage:
            bad = dataclasses.replace(state, tick=k + 5, status="error", error="must be dropped")
            for payload in junk(bad, dataclasses.replace(bad, robot=other, tick=k) if other is not None else None):
                self.transport.put(self.keys.state(rid), payload)
            fake_done = Done(robot=rid, tick=k, cell=robot.cell)
            for payload in junk(fake_done, dataclasses.replace(fake_done, robot=other) if other is not None else None):
                self.transport.put(self.keys.done(rid), payload)
        with self.cv:
            robot.reported.add(k)  # before the put: the UAV cannot legitimately have it earlier
        self._put(robot, self.keys.state(rid), state)
        if garbage and robot.last_state is not None:
            self._put(robot, self.keys.state(rid), robot.last_state)  # the previous tick's state, resent late
        robot.last_state = state
        if arrived and robot.done_for != plan.plan_id:
            done = Done(robot=rid, tick=k, cell=robot.cell)
            with self.cv:
                robot.done_for = plan.plan_id
                self.log.dones.append((time.monotonic(), done))
            self._put(robot, self.keys.done(rid), done)
            if rid in self.behaviour.garbage:
                self._put(robot, self.keys.done(rid), done)  # a resent Done

    def _end(self) -> None:
        # Robots leave on MissionEnd, withdrawing their tokens.
        with self.cv:
            for robot in self.robots.values():
                if robot.token is not None:
                    robot.token.close()
                    robot.token = None


# ---------------------------------------------------------------- one mission
@dataclass
class MissionRun:
    """A finished run of the UAV under test: its exit, its output, and what the site and the robots saw."""
    code: int | None          # None: still running at the mission timeout, killed
    started: float            # monotonic time of the UAV's start
    exited: float             # monotonic time its exit was seen
    stdout: str
    stderr: str
    log: Observed
    truth: Any
    record: Record
    vehicle: dict[str, Any] | None
    behaviour: Misbehaviour

    @property
    def seconds(self) -> float:
        return self.exited - self.started

    def __repr__(self) -> str:
        return f"MissionRun(exit {self.code}, {self.seconds:.1f} s, {self.log!r})"

    def tail(self, chars: int = 2500) -> str:
        return f"--- UAV stdout ---\n{self.stdout[-chars:]}\n--- UAV stderr ---\n{self.stderr[-chars:]}"

    def first_plans(self) -> dict[int, Plan]:
        """Each robot's first plan that reached it while its token was up."""
        out: dict[int, Plan] = {}
        for _, rid, plan, up in self.log.plans:
            if up:
                out.setdefault(rid, plan)
        return out


def run_mission(opts: UavOptions, behaviour: Misbehaviour, workdir: Path, late_join_s: float = LATE_JOIN_S) -> MissionRun:
    """Start router, world, robots and the UAV under test; run until the UAV exits; stop everything."""
    workdir.mkdir(parents=True, exist_ok=True)
    out, err = workdir / "uav.stdout", workdir / "uav.stderr"
    with Hub() as hub:
        site = Site(hub, opts)
        try:
            fleet = FakeFleet(hub.endpoint, hub.keys, site.truth, behaviour, opts.connectivity)
            try:
                argv = uav_command(opts.cmd, fleet=hub.fleet, endpoint=hub.endpoint, mavlink_port=site.mavlink_port,
                                   robots=opts.robots, tick_timeout=opts.tick_timeout_s)
                started = time.monotonic()
                proc = start_process(argv, out, err)
                try:
                    code = _drive(proc, fleet, behaviour, started + opts.mission_timeout_s, late_join_s)
                    exited = time.monotonic()
                finally:
                    if proc.poll() is None:
                        stop_process(proc)
                        exited = time.monotonic()
                # Its last messages and the token's withdrawal may still be on their way.
                fleet.until(lambda: bool(fleet.log.ends) and bool(fleet.log.uav_alive)
                            and not fleet.log.uav_alive[-1][1], SETTLE_S)
            finally:
                fleet.close()
            log = fleet.log  # closed: nothing changes it any more
            return MissionRun(code=code, started=started, exited=exited,
                              stdout=out.read_text(errors="replace"), stderr=err.read_text(errors="replace"),
                              log=log, truth=site.truth, record=site.record(), vehicle=site.vehicle(),
                              behaviour=behaviour)
        finally:
            site.close()


def _drive(proc: subprocess.Popen, fleet: FakeFleet, behaviour: Misbehaviour, deadline: float,
           late_join_s: float) -> int | None:
    if behaviour.late:
        # Late robots come up once the UAV is ready to dispatch (status phase or a first plan), or
        # `late_join_s` after its token appeared: a UAV that does not wait for the robots' tokens has
        # usually sent its plans by then, and one that waits (before perceiving, or before dispatching)
        # is kept waiting.
        def due() -> bool:
            # The UAV is up when its token is, or (a UAV without a token) when it first speaks.
            ups = [t for t, alive in fleet.log.uav_alive if alive] + [t for t in [fleet.log.first_status] if t]
            return (fleet.dispatching() or proc.poll() is not None
                    or (bool(ups) and time.monotonic() >= min(ups) + late_join_s))
        fleet.until(due, max(0.0, deadline - time.monotonic()))
        if fleet.dispatching():
            time.sleep(0.5)  # the window in which a UAV that does not wait would send the late robots' plans
        for rid in sorted(behaviour.late):
            fleet.join(rid)
    try:
        return proc.wait(max(0.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        return None


def error_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]
