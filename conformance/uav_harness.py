"""A harness that plays router, world and robots around a UAV implementation under test.

The UAV conformance suite (`test_uav_conformance.py` beside this file) starts
the UAV from a command line and surrounds it with: a Zenoh router on a free
loopback port, our real world in this process (ground truth, move service,
camera, and the simulated MAVLink vehicle on a free UDP port), and a fleet of
fake robots that the suite controls. The robots keep the contract of
docs/protocol.md (or break it on purpose: they stall, err, deviate, vanish, go
deaf or mute), and record everything the UAV sends them, with the checks that
can only be made at the moment a message arrives (was this robot's token up?
had every robot reported the previous tick?). The site records what the world
saw: when each image's shutter opened, and the images it sent.
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
from typing import Any, Callable

from protocol.codec import decode, encode
from protocol.config import client_config
from protocol.errors import MissionError, ProtocolError
from protocol.grid import Cell, on_grid
from protocol.keys import Keys, robot_id_from_key
from protocol.messages import (PROTOCOL_VERSION, CameraFrame, Done, Message, MissionEnd, MissionEvent, MissionStatus,
                               MoveBatch, MoveBatchResult, Plan, PlanAck, Record, RobotState, StateBatch, Tick,
                               VehiclePose)
from protocol.transport import Handle, IncomingQuery, ZenohTransport

from . import REPO, Hub, Waiter, stop_process

DEFAULT_UAV_CMD = (shlex.quote(sys.executable) + " -m uav_agent --fleet {fleet} --connect {endpoint} "
                   "--mavlink {mavlink} --robots {robots} --tick-timeout {tick_timeout}")
PLACEHOLDERS = "{fleet} {endpoint} {mavlink} {mavlink_port} {robots} {tick_timeout}"
MOVE_TIMEOUT_S = 5.0    # the contract's robot-side move query timeout
SETTLE_S = 2.0          # after the UAV exits: the longest wait for its last messages and token to arrive
ABORT_SLACK_S = 10.0    # beyond the tick timeout, for a failing UAV to say so, end the mission and exit
LATE_JOIN_S = 3.0       # after the UAV's token: when a late robot comes up, unless the UAV dispatches earlier
FIRST_ACK_DELAY_S = 0.5  # the fleet's first ack comes this late, as a real robot's may: a UAV must wait for it
LOST_SETTLE_S = 1.0     # a robot's token is gone this long before the others report the tick it vanished on
FUTURE_DELAY_S = 1.0    # a robot that put a state for a tick not yet put reports that tick this much later
RTL_HOLD_S = 2.0        # after the ground station's RTL is seen in the vehicle: the fleet holds its states so long
RTL_SEEN_S = 5.0        # at most this long for the vehicle to switch to RTL
STARTUP_WAIT_S = 30.0   # docs/protocol.md, Timeouts and waits: the UAV's wait for the world, for every robot, for acks
QUERY_WAIT_S = 10.0     # ... for an answer from world/info and world/record
CALM_TICKS = 3          # a scheduled deviation or stall comes at least this many ticks after the last fault
MUST_DROP = "must be dropped"   # the error text of every message the harness puts that a UAV must drop


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
@dataclass(frozen=True)
class Shutter:
    """An image's exposure as the world fixed it: when, and how settled the floor was."""
    at: float            # monotonic time
    judged: int          # the last tick the world judged
    heard: int           # the last Tick the world heard from the UAV
    open_tick: int | None  # a tick whose moves were being collected (None: none)

    @property
    def settled(self) -> bool:
        return self.open_tick is None and self.judged >= self.heard


class _Tap:
    """An incoming camera query whose reply is also handed to `sink` (the world's image, as sent)."""

    def __init__(self, query: IncomingQuery, sink: Callable[[bytes], None]) -> None:
        self._query, self._sink = query, sink

    def reply(self, payload: bytes) -> None:
        self._sink(payload)
        self._query.reply(payload)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._query, name)


class Site:
    """Our world in this process: the floor's truth, the move service, the camera and the MAVLink vehicle."""

    def __init__(self, hub: Hub, opts: UavOptions) -> None:
        from sim_world.config import WorldConfig
        from sim_world.service import World

        self.mavlink_port = free_udp_port()
        self.gcs_port = free_udp_port()   # the operator's link (the flight link answers the UAV only)
        self.shutters: list[Shutter] = []
        self.images: list[dict[str, Any]] = []      # the header of every image the world sent
        self._lock = threading.Lock()
        self.world = World(WorldConfig(fleet=hub.fleet, map=opts.map, robots=opts.robots, seed=opts.seed,
                                       connectivity=opts.connectivity, time_scale=opts.time_scale,
                                       mavlink=f"udpout:127.0.0.1:{self.mavlink_port}",
                                       gcs=f"udpin:127.0.0.1:{self.gcs_port}", connect=[hub.endpoint]))
        # Watched, not changed: when each shutter opens (how settled the floor is then), and what is sent.
        exposure, render = self.world.exposure, self.world._render_reply
        self.world.exposure = lambda: (self._shutter(), exposure())[1]
        self.world._render_reply = lambda q, shot, *rest: render(_Tap(q, self._sent), shot, *rest)
        try:
            self.world.start()
        except BaseException:
            self.world.close()
            raise

    def _shutter(self) -> None:
        desk = self.world.desk
        if desk is None:
            return
        with desk.cv:
            shot = Shutter(time.monotonic(), desk.judge.tick, desk.seen, desk.tick)
        with self._lock:
            self.shutters.append(shot)

    def _sent(self, payload: bytes) -> None:
        head = bytes(payload).split(b"\x00", 1)[0]
        try:
            with self._lock:
                self.images.append(json.loads(head))
        except ValueError:
            pass

    @property
    def truth(self):
        return self.world.truth

    def record(self) -> Record:
        return self.world.record()

    def vehicle(self) -> dict[str, Any] | None:
        return self.world.vehicle_dict()

    def command_rtl(self) -> float | None:
        """A ground station on the vehicle's ground-station link commands Return To Launch, as an operator's
        QGroundControl or a failsafe would; returns when the vehicle switched (None: it did not)."""
        from pymavlink import mavutil

        vehicle = self.world.vehicle
        if vehicle is None:
            return None
        gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{self.gcs_port}", source_system=250)
        try:
            gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
            deadline = time.monotonic() + RTL_SEEN_S
            while time.monotonic() < deadline:
                if vehicle.mode.name == "RTL":
                    return time.monotonic()
                time.sleep(0.02)
            return None
        finally:
            gcs.close()

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
    gone: bool = False                  # its token vanished for good (lost): it does nothing any more
    frozen: int = 0                     # ticks of a stall still to sit out
    deviated: bool = False              # its one deviation is behind it
    ignored_repair: str = ""            # the repair plan it ignores every put of


@dataclass
class Observed:
    """What the UAV sent and what the fleet answered, in arrival order, with monotonic times."""
    plans: list[tuple[float, int, Plan, bool]] = field(default_factory=list)  # time, key's robot, plan, token up
    ticks: list[tuple[float, Tick]] = field(default_factory=list)
    statuses: list[tuple[float, MissionStatus]] = field(default_factory=list)
    events: list[tuple[float, MissionEvent]] = field(default_factory=list)
    poses: list[tuple[float, VehiclePose]] = field(default_factory=list)
    frames: list[tuple[float, CameraFrame]] = field(default_factory=list)
    ends: list[tuple[float, MissionEnd]] = field(default_factory=list)
    uav_alive: list[tuple[float, bool]] = field(default_factory=list)
    seqs: list[tuple[str, int]] = field(default_factory=list)          # (kind, seq) of every UAV message
    acks: list[tuple[float, PlanAck]] = field(default_factory=list)
    dones: list[tuple[float, Done]] = field(default_factory=list)
    joined: dict[int, float] = field(default_factory=dict)              # robot -> when its token went up
    # What the harness did wrong on purpose: (kind, robot, tick, time), e.g. ("lost", 2, 4, t) for a
    # robot whose token vanished after its state of tick 4 was put.
    faults: list[tuple[str, int, int, float]] = field(default_factory=list)
    violations: list[tuple[str, str]] = field(default_factory=list)    # (kind, text): the UAV broke the contract
    harness: list[str] = field(default_factory=list)                    # the suite's own trouble (world silent)

    @property
    def first_status(self) -> float | None:
        """When the UAV's first status came."""
        return self.statuses[0][0] if self.statuses else None

    def of(self, *kinds: str) -> list[str]:
        return [text for kind, text in self.violations if kind in kinds]

    def fault(self, kind: str, robot: int | None = None) -> tuple[str, int, int, float] | None:
        """The first fault of `kind` the harness made (of `robot`, if given)."""
        return next((f for f in self.faults if f[0] == kind and robot in (None, f[1])), None)

    def __repr__(self) -> str:  # short: pytest prints it in every failed assertion that mentions it
        return (f"Observed({len(self.plans)} plans, {len(self.ticks)} ticks, {len(self.ends)} ends, "
                f"{len(self.acks)} acks, {len(self.dones)} dones, {len(self.faults)} faults, "
                f"{len(self.violations)} violations)")


class FakeFleet(Waiter):
    """Robots in this process, on one client session: they answer as the contract says and watch the UAV."""

    def __init__(self, endpoint: str, keys: Keys, truth: Any, behaviour: Misbehaviour, connectivity: int = 4,
                 rtl: Callable[[], float | None] | None = None) -> None:
        Waiter.__init__(self)
        self.keys, self.truth, self.behaviour, self.connectivity = keys, truth, behaviour, connectivity
        self.robots = {rid: FakeRobot(rid, tuple(cell)) for rid, cell in sorted(truth.starts.items())}
        self.log = Observed()
        self.seen_tick = 0     # the highest tick the worker has executed
        self._rtl = rtl
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
                t.subscribe(k.mission_event, self._on_event),
                t.subscribe(k.uav_pose, self._on_pose),
                t.subscribe(k.uav_frame, self._on_frame),
                t.watch_alive(k.alive_uav, self._on_uav),
            ]
            self._worker = threading.Thread(target=self._work, name="conformance-robots", daemon=True)
            self._worker.start()
            for rid in self.robots:
                if rid not in behaviour.late and rid not in behaviour.absent:
                    self.join(rid)
        except BaseException:
            self.transport.close()
            raise

    # ------------------------------------------------------------ control
    def join(self, rid: int) -> None:
        """Declare robot `rid`'s liveliness token (a late robot comes up)."""
        with self.cv:
            robot = self.robots[rid]
            if robot.token is None and not robot.gone:
                robot.token = self.transport.announce(self.keys.alive_robot(rid))
                self.log.joined[rid] = time.monotonic()
            self.cv.notify_all()

    def dispatching(self) -> bool:
        """The UAV has said it is about to send plans (status phase), or has sent one."""
        with self.cv:
            return bool(self.log.plans) or any(s.phase == "dispatch" for _, s in self.log.statuses)

    def close(self) -> None:
        self._jobs.put(None)
        self._worker.join(MOVE_TIMEOUT_S + RTL_SEEN_S + RTL_HOLD_S + 1)
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
        if cls not in (CameraFrame, VehiclePose):   # an image keeps its number, the pose stream counts its own
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
            ended = bool(self.log.ends)
            self.cv.notify_all()
        if ended:
            self._violation("after-end", f"plan {plan.plan_id} to robot {rid} after MissionEnd")
        if robot is None:
            self._violation("plan-unknown", f"plan {plan.plan_id} on {key}: no such robot in the world")
        elif not up:
            # A real robot is not listening yet (or any more): the plan is lost.
            self._violation("plan-before-token", f"plan {plan.plan_id} sent to robot {rid} while its token was down")
        elif rid in self.behaviour.deaf and self._lost_on_the_way(rid, plan):
            return  # the first puts of its first plan never reach it: the UAV must put it again
        elif rid in self.behaviour.deaf_repair and plan.start_tick > 0 and robot.ignored_repair in ("", plan.plan_id):
            if not robot.ignored_repair:
                robot.ignored_repair = plan.plan_id
                self._fault("deaf-repair", rid, plan.start_tick)
            return  # its first repair never reaches it, however often it is put
        else:
            self._jobs.put(("plan", rid, plan))

    def _lost_on_the_way(self, rid: int, plan: Plan) -> bool:
        with self.cv:
            mine = [p.plan_id for _, r, p, up in self.log.plans if r == rid and up]
        return mine[0] == plan.plan_id and len(mine) <= self.behaviour.deaf_puts

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
                           if (prev == 0 or tick.plan_id in r.sent) and not r.acked.get(tick.plan_id)
                           and not r.ignored_repair == tick.plan_id]
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

    def _keep(self, into: list, key: str, payload: bytes, cls: type) -> None:
        msg = self._decode(key, payload, cls)
        if msg is not None:
            with self.cv:
                into.append((time.monotonic(), msg))
                self.cv.notify_all()

    def _on_status(self, key: str, payload: bytes) -> None:
        self._keep(self.log.statuses, key, payload, MissionStatus)

    def _on_event(self, key: str, payload: bytes) -> None:
        self._keep(self.log.events, key, payload, MissionEvent)

    def _on_pose(self, key: str, payload: bytes) -> None:
        self._keep(self.log.poses, key, payload, VehiclePose)

    def _on_frame(self, key: str, payload: bytes) -> None:
        self._keep(self.log.frames, key, payload, CameraFrame)

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

    def _fault(self, kind: str, rid: int, tick: int) -> None:
        with self.cv:
            self.log.faults.append((kind, rid, tick, time.monotonic()))
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
            # A repair (start_tick > 0) starts where the UAV's camera saw the robot: the world's
            # cell, which is where this robot stands (it never slips).
            problem = plan_problem(plan, rid, robot.cell, self.truth, self.connectivity)
        if problem:
            self._violation("bad-plan", f"robot {rid}, plan {plan.plan_id}: {problem}")
        ok = not problem and rid not in self.behaviour.refuse
        error = problem or ("" if ok else "refused on purpose by the conformance suite")
        if rid in self.behaviour.garbage:
            other = self._other(rid)
            fake = PlanAck(robot=rid, plan_id=plan.plan_id, ok=False, error=MUST_DROP)
            for payload in junk(fake, dataclasses.replace(fake, robot=other) if other is not None else None):
                self.transport.put(self.keys.ack(rid), payload)
        ack = PlanAck(robot=rid, plan_id=plan.plan_id, ok=ok, error=error, protocol=PROTOCOL_VERSION)
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
            if plan is not None and tick.plan_id in robot.sent and tick.plan_id != robot.ignored_repair:
                self._violation("tick-plan-id", f"Tick {tick.k} names plan {tick.plan_id}, robot {robot.rid} "
                                                f"holds {plan.plan_id}")
            return robot.cell  # the contract: a tick for another plan (or none) means stay
        i = tick.k - robot.base
        return tuple(plan.path[max(0, min(i, len(plan.path) - 1))])

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

    def _tick(self, tick: Tick) -> None:
        if tick.k <= self.seen_tick:
            return  # a resent or late tick: already executed
        k, b = tick.k, self.behaviour
        vanished = [self.robots[r] for r, at in b.vanish_at.items() if at == k and r in self.robots]
        for robot in vanished:   # killed as the tick arrived: it asks and reports nothing more
            self._vanish(robot, "vanished", k)
        if vanished:
            time.sleep(LOST_SETTLE_S)   # the others are mid-tick when the UAV hears of it
        with self.cv:
            for rid, (first, ticks) in b.stall.items():
                robot = self.robots.get(rid)
                if robot is not None and k >= first and not self.log.fault("stall", rid) and self._calm(k):
                    robot.frozen = ticks
                    self.log.faults.append(("stall", rid, k, time.monotonic()))
            asking = [r for r in self.robots.values() if self._asks(r, k)]
            targets = {r.rid: self._target(r, tick) for r in asking}
            purpose = {}
            for r in asking:
                why = self._stays_on_purpose(r, k, targets)
                if why:
                    purpose[r.rid] = why
                    targets[r.rid] = r.cell
            self._make_way(targets)
            moves = [(rid, self.robots[rid].cell, targets[rid]) for rid in sorted(targets)]
            for r in self.robots.values():
                r.frozen = max(0, r.frozen - 1)   # a frozen robot sits this tick out
            for rid, why in purpose.items():
                if why != "stuck" or not self.log.fault("stuck", rid):
                    self.log.faults.append((why, rid, k, time.monotonic()))
        results = []
        if moves:
            # All robots' moves in one query: the world judges a tick once every robot has asked.
            replies = self.transport.request(self.keys.move, encode(MoveBatch(tick=k, moves=moves)), MOVE_TIMEOUT_S)
            if not replies:
                raise MissionError(f"the world did not answer the moves of tick {k}")
            results = decode(replies[0], MoveBatchResult).results
        self.seen_tick = k
        for rid in b.liar & set(self.robots):
            self._lie(self.robots[rid], tick)
        with self.cv:
            for rid, accepted, cell, reason in results:
                self.robots[rid].cell = tuple(cell)
        # A robot lost at this tick reports it, then its token vanishes; the others report once the UAV
        # has had time to hear of it: a UAV that watches liveliness holds the fleet, one that does not
        # finds its barrier complete.
        lost = [rid for rid, *_ in results if b.lost_at.get(rid) == k]
        order = sorted(results, key=lambda res: res[0] not in lost)
        if b.rtl_at == k and self._rtl is not None:
            seen = self._rtl()
            if seen is None:
                raise MissionError("the vehicle did not switch to RTL when the ground station commanded it")
            self._fault("rtl", -1, k)
            time.sleep(RTL_HOLD_S)   # a UAV that watches its vehicle ends the mission before it could tick on
        delayed = []
        for rid, accepted, cell, reason in order:
            robot = self.robots[rid]
            if k >= b.silent_from.get(rid, k + 1):
                continue  # executes the tick but stops reporting: the UAV's barrier must hold
            if rid in b.garbage and k == 3:
                delayed.append((robot, accepted, reason))   # it put a state for this tick before the tick
                continue
            self._report(robot, tick, accepted, reason, "error" if b.error_at.get(rid) == k else "")
            if rid in lost:
                self._vanish(robot, "lost", k)
                if rid == lost[-1]:
                    time.sleep(LOST_SETTLE_S)
        if delayed:
            time.sleep(FUTURE_DELAY_S)
            for robot, accepted, reason in delayed:
                self._report(robot, tick, accepted, reason, "")

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

    def _report(self, robot: FakeRobot, tick: Tick, accepted: bool, reason: str, error: str) -> None:
        plan, rid, k = robot.plan, robot.rid, tick.k
        arrived = (plan is not None and plan.plan_id == tick.plan_id and k - robot.base >= len(plan.path) - 1
                   and robot.cell == tuple(plan.goal))
        status = "error" if error else ("done" if arrived else "stepping")
        state = RobotState(robot=rid, tick=k, cell=robot.cell, status=status, plan_id=plan.plan_id if plan else "",
                           error="its drive failed (the conformance suite)" if error else ("" if accepted else reason))
        garbage = rid in self.behaviour.garbage and k <= 3
        if garbage:
            self._garbage(robot, state)
        if garbage and k == 2:
            self._future(robot, state, tick)   # before its state of 2: the UAV cannot have put Tick 3 yet
        with self.cv:
            robot.reported.add(k)  # before the put: the UAV cannot legitimately have it earlier
        self._put(robot, self.keys.state(rid), state)
        if garbage and robot.last_state is not None:
            self._put(robot, self.keys.state(rid), robot.last_state)  # the previous tick's state, resent late
        robot.last_state = state
        if error:
            return
        if arrived and robot.done_for != plan.plan_id:
            done = Done(robot=rid, tick=k, cell=robot.cell)
            with self.cv:
                robot.done_for = plan.plan_id
                if rid in self.behaviour.mute:
                    return   # it has arrived, and says nothing: the camera must see it
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
    record: Record | None     # None: no world (a stranded UAV)
    vehicle: dict[str, Any] | None
    behaviour: Misbehaviour
    shutters: list[Shutter] = field(default_factory=list)
    images: list[dict[str, Any]] = field(default_factory=list)   # headers of the images the world sent
    robots: int = 0

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

    def plans_by_id(self) -> dict[str, dict[int, Plan]]:
        """Every plan put, by plan_id then robot (the last put of each), in the order the ids first came."""
        out: dict[str, dict[int, Plan]] = {}
        for _, rid, plan, _ in self.log.plans:
            out.setdefault(plan.plan_id, {})[rid] = plan
        return out


def run_mission(opts: UavOptions, behaviour: Misbehaviour, workdir: Path, late_join_s: float = LATE_JOIN_S) -> MissionRun:
    """Start router, world, robots and the UAV under test; run until the UAV exits; stop everything."""
    workdir.mkdir(parents=True, exist_ok=True)
    out, err = workdir / "uav.stdout", workdir / "uav.stderr"
    with Hub() as hub:
        site = Site(hub, opts)
        try:
            fleet = FakeFleet(hub.endpoint, hub.keys, site.truth, behaviour, opts.connectivity,
                              rtl=site.command_rtl if behaviour.rtl_at else None)
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
                              behaviour=behaviour, shutters=list(site.shutters), images=list(site.images),
                              robots=opts.robots)
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
        for rid in sorted(behaviour.late - behaviour.absent):
            fleet.join(rid)
    try:
        return proc.wait(max(0.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        return None


# ---------------------------------------------------------------- a UAV without its world
WORLDS = ("none", "silent", "garbage")   # no world; a world that answers world/info nothing; or garbage


class _Watcher(Waiter):
    """What a UAV without a working world puts: its token, its mission end."""

    def __init__(self, hub: Hub) -> None:
        Waiter.__init__(self)
        self.log = Observed()
        t, k = hub.transport, hub.keys
        self.handles = [t.subscribe(k.mission_end, self._on_end), t.watch_alive(k.alive_uav, self._on_uav)]

    def _on_end(self, key: str, payload: bytes) -> None:
        try:
            end = decode(payload, MissionEnd)
        except ProtocolError as exc:
            end = None
            self.log.violations.append(("malformed", f"the UAV put an unreadable message on {key}: {exc}"))
        with self.cv:
            if end is not None:
                self.log.ends.append((time.monotonic(), end))
            self.cv.notify_all()

    def _on_uav(self, _key: str, alive: bool) -> None:
        with self.cv:
            self.log.uav_alive.append((time.monotonic(), alive))
            self.cv.notify_all()

    def close(self) -> None:
        for h in self.handles:
            h.close()


def run_stranded(opts: UavOptions, world: str, workdir: Path, timeout_s: float) -> MissionRun:
    """Start the UAV under test on a router with no world (`none`), or with a world whose token is up
    but which answers `world/info` with nothing (`silent`: the query ends without a reply) or with
    garbage (`garbage`); no vehicle. Run until it exits, at most `timeout_s`."""
    workdir.mkdir(parents=True, exist_ok=True)
    out, err = workdir / "uav.stdout", workdir / "uav.stderr"
    with Hub() as hub:
        handles: list[Handle] = []
        watcher = _Watcher(hub)
        try:
            if world != "none":
                def answer(q: IncomingQuery) -> None:
                    if world == "garbage":
                        q.reply(b'{"type":"WorldInfo","v":1,"width":"wide"}')
                    else:
                        q.finish()
                handles.append(hub.transport.serve(hub.keys.world_info, answer))
                handles.append(hub.transport.announce(hub.keys.alive_world))
            argv = uav_command(opts.cmd, fleet=hub.fleet, endpoint=hub.endpoint, mavlink_port=free_udp_port(),
                               robots=opts.robots, tick_timeout=opts.tick_timeout_s)
            started = time.monotonic()
            proc = start_process(argv, out, err)
            try:
                try:
                    code: int | None = proc.wait(timeout_s)
                except subprocess.TimeoutExpired:
                    code = None
                exited = time.monotonic()
            finally:
                if proc.poll() is None:
                    stop_process(proc)
                    exited = time.monotonic()
            watcher.until(lambda: bool(watcher.log.uav_alive) and not watcher.log.uav_alive[-1][1], SETTLE_S)
        finally:
            watcher.close()
            for h in handles:
                h.close()
        return MissionRun(code=code, started=started, exited=exited, stdout=out.read_text(errors="replace"),
                          stderr=err.read_text(errors="replace"), log=watcher.log, truth=None, record=None,
                          vehicle=None, behaviour=Misbehaviour(), robots=opts.robots)


def error_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]
