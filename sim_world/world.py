"""The world process: ground truth, the vehicle, the camera and the move service on Zenoh.

It owns what physically exists: the floor, where every robot stands, the goal
markers and the multicopter. It serves, under `uavr/<fleet>/world/`:
`info` (site calibration), `camera` (the image seen from the vehicle's current
pose), `move` (one tick's moves, judged together) and `record` (what happened,
for scoring); it also takes moves put ahead (`ahead/<ids>`, judged when the
UAV's Tick comes, answered on `judged/<ids>`: sim_world/ahead.py). It announces
`alive/world` once all of them are declared.

    python -m sim_world --fleet F --connect tcp/127.0.0.1:7447 --robots 8
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable, NamedTuple

import numpy as np

from protocol.config import add_session_arguments
from protocol.errors import MissionError, ProtocolError, UavRobotsError
from protocol.keys import DEFAULT_FLEET, Keys, ids_of_ahead_key, ids_of_move_key, robot_id_from_key
from protocol.log import Throttled
from protocol.mapfile import Cell, format_rows, read_scen
from protocol.messages import (CameraRequest, MissionEnd, MoveAhead, MoveBatch, MoveBatchResult, MoveRequest, MoveResult,
                               MovesJudged, Record, RecordRequest, Tick, WorldInfo, WorldInfoRequest, decode, encode)
from protocol.process import Lifecycle
from protocol.transport import IncomingQuery, Transport, open_session
from scenarios.landmarks import LandmarkSet
from scenarios.limits import check_fleet, check_floor
from scenarios.maps import place, resolve_map

from .camera.model import DEFAULT_CAMERA_PRESET, camera_model_from, camera_options
from .moves import MoveJudge
from .vehicle_cli import DEFAULT_URL as DEFAULT_VEHICLE_URL
from .vehicle_cli import add_ground_station_arguments, parse_home

# PX4 SITL's default home: a field near Zurich. The grid's top-left corner is there.
HOME = (47.397742, 8.545594, 488.0)
MOVE_BATCH_TIMEOUT_S = 2.0
# Following an autopilot, an image waits at most this long for the telemetry after its shutter (at
# 50 Hz the next sample is 20 ms away); then the last sample is carried on at its velocity.
FOLLOW_WAIT_S = 0.25


@dataclass
class WorldConfig:
    fleet: str
    map: str = "warehouse-small"
    robots: int = 8
    seed: int = 0
    scen: str | None = None           # a MovingAI .scen: starts and goals from its first `robots` lines
    connectivity: int = 4
    cell_size_m: float = 1.0
    home_lat: float = HOME[0]
    home_lon: float = HOME[1]
    home_alt_m: float = HOME[2]
    mavlink: str | None = "udpout:127.0.0.1:14540"   # None: no vehicle (tests of the services alone)
    gcs: str | None = None            # a second MAVLink link, for a ground station
    mavlink_key: str | None = None    # a file with the MAVLink 2 signing key of the gcs link
    mavlink_bind: str = "127.0.0.1"   # the address the vehicle's sockets are bound to
    # Follow an autopilot the world does not fly (sim_world/pose_follower.py): its pose link, and where
    # its local origin lies on the floor (None: its first home is the floor's corner).
    autopilot_pose: str | None = None
    autopilot_origin: tuple[float, float, float] | None = None
    time_scale: float = 1.0
    camera: dict[str, Any] = field(default_factory=dict)  # sim_world.camera.CameraModel fields
    camera_height_m: float = 0.3      # lens above the floor when the vehicle sits on it
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    zenoh_config: str | None = None
    move_batch_timeout_s: float = MOVE_BATCH_TIMEOUT_S
    slip: float = 0.0                 # probability that a move ends elsewhere, unknown to the robot
    skids: dict[int, int] = field(default_factory=dict)   # robot -> tick from which all its moves end elsewhere
    end_timeout_s: float = 120.0      # after MissionEnd, the longest wait for the UAV to leave
    camera_mavlink: str | None = None  # the camera's own MAVLink link (camera/mavlink_camera.py); None: none
    camera_video: str | None = None    # udp://HOST:PORT: its H.264 RTP stream (camera/stream.py); None: none

    def check(self) -> None:
        Keys(self.fleet)
        check_fleet(self.robots)
        if self.connectivity not in (4, 8):
            raise UavRobotsError(f"connectivity must be 4 or 8, got {self.connectivity}")
        if not self.cell_size_m > 0:
            raise UavRobotsError(f"cell size must be positive, got {self.cell_size_m}")
        if not self.move_batch_timeout_s > 0:
            raise UavRobotsError(f"the move batch timeout must be positive, got {self.move_batch_timeout_s}")
        if not self.time_scale > 0:
            raise UavRobotsError(f"time scale must be positive, got {self.time_scale}")
        if self.connect and self.listen:
            raise UavRobotsError("give --connect or --listen, not both")
        if self.autopilot_pose:
            from .pose_follower import check_pose_url
            if self.gcs or self.mavlink_key:   # its `mavlink` is not opened
                raise UavRobotsError("with --autopilot-pose the world runs no vehicle: give --gcs and --mavlink-key "
                                     "to the autopilot (`uav-robots vehicle`)")
            check_pose_url(self.autopilot_pose, self.mavlink_bind)
        elif self.mavlink:
            vehicle_config(self)
        elif self.gcs or self.mavlink_key:
            raise UavRobotsError("--gcs and --mavlink-key need a vehicle (--mavlink is none)")


def vehicle_config(cfg: WorldConfig, hover_wobble_deg: float = 0.0) -> Any:
    """The vehicle's configuration, checked (links, bind address, signing key): one-line errors."""
    from .vehicle.config import VehicleConfig, read_signing_key

    if cfg.mavlink_key and not cfg.gcs:
        raise UavRobotsError("--mavlink-key signs the ground-station link: give --gcs URL too")
    try:  # bad input, not a failed mission: exit 2
        key = read_signing_key(cfg.mavlink_key) if cfg.mavlink_key else None
        return VehicleConfig(url=cfg.mavlink or "udpout:127.0.0.1:14540", home_lat=cfg.home_lat,
                             home_lon=cfg.home_lon, home_alt_m=cfg.home_alt_m, time_scale=cfg.time_scale,
                             gcs_url=cfg.gcs, signing_key=key, bind_host=cfg.mavlink_bind,
                            hover_wobble_deg=hover_wobble_deg, seed=cfg.seed)
    except MissionError as exc:
        raise UavRobotsError(str(exc)) from None


def fence_reach_m(shape: tuple[int, ...], cell_size_m: float) -> float:
    """The geofence radius that keeps a floor of `shape` cells inside: its farthest corner, with a margin."""
    h, w = shape[:2]
    return 1.2 * math.hypot(h, w) * cell_size_m + 10.0


@dataclass(frozen=True)
class Truth:
    name: str
    free: np.ndarray
    starts: dict[int, Cell]
    goals: list[Cell]


def build_truth(cfg: WorldConfig) -> Truth:
    name, free = resolve_map(cfg.map, cfg.seed, check_floor)
    if cfg.scen:
        agents = read_scen(cfg.scen, free, cfg.robots)
        starts, goals = [a.start for a in agents], [a.goal for a in agents]
    else:
        placement = place(free, cfg.robots, cfg.seed)
        starts, goals = placement.starts, placement.goals
    return Truth(name, free, {i: c for i, c in enumerate(starts)}, list(goals))


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
        _send(sends)

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
            _send(sends)

    def close(self) -> None:
        with self.cv:
            self._closed = True
            self.cv.notify_all()
        self._timer.join(2.0)


def _send(sends: list[tuple[Reply, MoveResult]]) -> None:
    for reply, res in sends:
        try:
            reply(res)
        except Exception as exc:  # noqa: BLE001 - one asker gone must not stop the others' answers
            print(f"warning: world: a move reply failed: {exc}", file=sys.stderr, flush=True)


class World(Lifecycle):
    def __init__(self, cfg: WorldConfig, transport: Transport | None = None) -> None:
        super().__init__()
        cfg.check()
        self.cfg = cfg
        self.keys = Keys(cfg.fleet)
        self.truth = build_truth(cfg)
        self.landmarks: LandmarkSet | None = None
        self.estimator: Any = None
        self.judge = MoveJudge(self.truth.free, dict(self.truth.starts), cfg.connectivity,
                               skid_prob=cfg.slip, skid_robots=dict(cfg.skids), seed=cfg.seed)
        self.desk: MoveDesk | None = None
        self.ahead: Any = None   # sim_world.ahead.AheadDesk, once started
        self.transport = transport
        self._own_transport = transport is None
        self.vehicle: Any = None
        self.follower: Any = None   # sim_world.pose_follower.PoseFollower, with --autopilot-pose
        self.camera_model: Any = None
        self.mavlink_camera: Any = None   # camera.mavlink_camera.MavlinkCamera, with --camera-mavlink/--camera-video
        self.warn = Throttled("world")
        self.mission_ended: float | None = None
        self.uav_seen = False
        self.uav_alive = False
        self._camera_pool = ThreadPoolExecutor(1, thread_name_prefix="camera")
        self._t0 = time.monotonic()
        self._seq = 0
        self._seq_lock = threading.Lock()

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        cfg = self.cfg
        from .camera import CameraModel
        try:
            self.camera_model = CameraModel(**cfg.camera)
        except TypeError as exc:
            raise UavRobotsError(f"camera options: {exc}") from None
        from .camera import PoseEstimator, prepare, scene_landmarks
        self.landmarks = scene_landmarks(self.truth.free, cfg.cell_size_m, self.camera_model)
        self.estimator = PoseEstimator(self.camera_model, cfg.seed)
        # The lens and noise tables take seconds at 12 MP: built on the camera's thread while the
        # vehicle takes off, so the first image is not late.
        self._camera_pool.submit(prepare, self.camera_model)
        if cfg.autopilot_pose:
            from .pose_follower import PoseFollower
            self.follower = PoseFollower(cfg.autopilot_pose, cfg.autopilot_origin, cfg.mavlink_bind, self.warn).start()
        elif cfg.mavlink:
            from .vehicle import Vehicle
            self.vehicle = Vehicle(vehicle_config(cfg, hover_wobble_deg=self.camera_model.wobble_deg))
            # The geofence must not cut off part of a large floor: the farthest corner, with a margin.
            reach = fence_reach_m(self.truth.free.shape, cfg.cell_size_m)
            if reach > self.vehicle.param("GF_MAX_HOR_DIST"):
                self.vehicle.set_param("GF_MAX_HOR_DIST", reach)
            self.vehicle.start()
        if self.transport is None:
            c = self.cfg
            self.transport = open_session("world", c.listen, c.connect, c.zenoh_config, self.stop, alone="either")
        self.desk = MoveDesk(self.judge, cfg.move_batch_timeout_s, self.warn)
        from .ahead import AheadDesk   # it builds on this module's MoveDesk
        self.ahead = AheadDesk(self.desk, self._put_judged)
        t, k = self.transport, self.keys
        self.keep(
            # In the order they were sent: a UAV flies on once an info query sent after its
            # camera query is answered, so the shutter must have opened by then.
            t.serve(k.world_info, self._on_info, inline=True),
            t.serve(k.camera, self._on_camera, inline=True),
            t.serve(k.move, self._on_move, inline=True),
            t.serve(k.moves_by_identity, self._on_move, inline=True),
            # Inline, so that a sender's moves and the UAV's Tick are taken in the order they came.
            t.subscribe(k.all_ahead, self._on_move_ahead, inline=True),
            t.subscribe(k.tick, self._on_tick, inline=True),
            t.serve(k.record, self._on_record),
            t.subscribe(k.mission_end, self._on_mission_end),
            t.watch_alive(k.alive_uav, self._on_uav),
            t.watch_alive(k.alive_robots, self._on_robot_alive),
        )
        self._start_camera_component()
        self.keep(t.announce(k.alive_world))

    def run(self, poll_s: float = 0.1) -> str:
        """Serve until stopped; returns why it stopped."""
        return self.serve(poll_s, self._check_end)

    def _check_end(self) -> None:
        if self.mission_ended is not None:
            waited = time.monotonic() - self.mission_ended
            # Stay while the UAV may still fetch the record and land the vehicle.
            if not self.uav_alive and (self.uav_seen or waited > 1.0):
                self.finish("mission ended")
            elif waited > self.cfg.end_timeout_s:
                self.finish(f"mission ended; the UAV stayed {self.cfg.end_timeout_s:g} s longer")

    def close(self) -> None:
        self.release()
        self.warn.flush()   # the warnings held back, said now rather than at exit
        if self.desk is not None:
            self.desk.close()
        if self.mavlink_camera is not None:
            self.mavlink_camera.close()
        self._camera_pool.shutdown(wait=True, cancel_futures=True)
        if self.follower is not None:
            self.follower.close()
            self.follower = None
        if self.vehicle is not None:
            try:
                self.vehicle.stop()
            finally:
                self.vehicle = None
        if self._own_transport and self.transport is not None:
            self.transport.close()
            self.transport = None

    def __enter__(self) -> "World":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def describe(self) -> str:
        h, w = self.truth.free.shape
        where = getattr(self.transport, "where", "zenoh")
        return (f"fleet {self.cfg.fleet}, map {self.truth.name} {w}x{h}, {len(self.truth.starts)} robots, "
                f"zenoh {where}, "
                + (f"following the autopilot on {self.cfg.autopilot_pose}" if self.cfg.autopilot_pose
                   else f"mavlink {self.cfg.mavlink or 'off'}")
                + (f", ground station {self.cfg.gcs}" + (" (signed)" if self.cfg.mavlink_key else "")
                   if self.cfg.gcs else ""))

    # ------------------------------------------------------------ handlers
    def _next_seq(self) -> int:
        with self._seq_lock:
            self._seq += 1
            return self._seq

    def _decode(self, q: IncomingQuery, cls: type, entries: int | None = None) -> Any:
        try:
            return decode(q.payload, cls, entries)
        except ProtocolError as exc:
            self.warn(f"{q.key}: {exc}")
            q.finish()
            return None

    def _on_info(self, q: IncomingQuery) -> None:
        if self._decode(q, WorldInfoRequest) is None:
            return
        h, w = self.truth.free.shape
        c = self.cfg
        marks = self.landmarks
        extra: dict[str, Any] = {}
        if marks is not None:
            extra = dict(landmark_family=marks.family, landmark_size_m=marks.size_m, landmarks=list(marks.landmarks))
        q.reply(encode(WorldInfo(width=w, height=h, cell_size_m=c.cell_size_m, home_lat=c.home_lat,
                                 home_lon=c.home_lon, home_alt_m=c.home_alt_m, seq=self._next_seq(), **extra)))

    def _asker_may_move(self, q: IncomingQuery, robots: list[int]) -> bool:
        """A move asked under `world/move/<ids>` is judged only for those ids: access control binds an
        identity to that key, so one robot cannot move another (the plain key carries no identity)."""
        try:
            allowed = ids_of_move_key(self.keys, q.key)
        except UavRobotsError as exc:
            allowed, why = [], str(exc)
        else:
            why = f"{q.key} may not move robot(s) {sorted(set(robots) - set(allowed or robots))[:5]}"
        if allowed is None or set(robots) <= set(allowed):
            return True
        self.warn(f"refused a move query: {why}")
        q.finish()
        return False

    def _on_move(self, q: IncomingQuery) -> None:
        batch = b'"MoveBatch"' in q.payload[:200]
        if batch:
            self._on_move_batch(q)
            return
        req = self._decode(q, MoveRequest)
        if req is None or not self._asker_may_move(q, [req.robot]):
            return
        seq = self._next_seq

        def reply(res: MoveResult) -> None:
            q.reply(encode(dataclasses.replace(res, seq=seq())))
        assert self.desk is not None
        self.desk.submit(req, reply)

    def _on_move_batch(self, q: IncomingQuery) -> None:
        """A pool's moves in one query: each is judged like a MoveRequest, answered all at once."""
        try:   # a key naming its robots bounds the batch's bytes by them (docs/protocol.md, Limits)
            named = ids_of_move_key(self.keys, q.key)
        except UavRobotsError:
            named = None
        batch = self._decode(q, MoveBatch, None if named is None else len(named))
        if batch is None or not self._asker_may_move(q, [r for r, _, _ in batch.moves]):
            return
        if not batch.moves:
            q.reply(encode(MoveBatchResult(tick=batch.tick, results=[], seq=self._next_seq())))
            return
        lock = threading.Lock()
        results: dict[int, MoveResult] = {}
        left = [len(batch.moves)]

        # One answerer for the whole batch, not one closure per move: at 1,000 robots the
        # per-move objects were a fifth of the world's time.
        def reply(res: MoveResult) -> None:
            with lock:
                results[res.robot] = res
                left[0] -= 1
                if left[0]:
                    return
            out = [(r.robot, r.accepted, r.cell, r.reason) for r in results.values()]
            q.reply(encode(MoveBatchResult(tick=batch.tick, results=out, seq=self._next_seq())))
        assert self.desk is not None
        self.desk.submit_many([(Ask(robot, batch.tick, frm, to), reply) for robot, frm, to in batch.moves])

    def _on_move_ahead(self, key: str, payload: bytes) -> None:
        """A MoveAhead put: judged for the robots its key names only (as a move query, see Security)."""
        try:
            allowed = ids_of_ahead_key(self.keys, key)
            msg = decode(payload, MoveAhead, len(allowed))
        except (ProtocolError, UavRobotsError) as exc:
            self.warn(f"{key[:80]}: {exc}")
            return
        foreign = sorted({r for r, _, _ in msg.moves} - set(allowed))
        if foreign:
            self.warn(f"refused moves put ahead: {key} may not move robot(s) {foreign[:5]}")
            return
        why = self.ahead.on_move_ahead(key.rsplit("/", 1)[1], msg)
        if why:
            self.warn(f"{key}: {why}")

    def _on_tick(self, key: str, payload: bytes) -> None:
        try:
            tick = decode(payload, Tick)
        except ProtocolError as exc:
            self.warn(f"{key}: {exc}")
            return
        self.ahead.on_tick(tick)

    def _put_judged(self, label: str, msg: MovesJudged) -> None:
        assert self.transport is not None
        self.transport.put(f"{self.keys.prefix}/world/judged/{label}",
                           encode(dataclasses.replace(msg, seq=self._next_seq())))

    def _on_record(self, q: IncomingQuery) -> None:
        if self._decode(q, RecordRequest) is None:
            return
        q.reply(encode(self.record()))

    def record(self) -> Record:
        assert self.desk is not None
        with self.desk.cv:
            j = self.judge
            return Record(ticks=j.tick, collisions=j.collisions, refused=j.refused_dicts(),
                          executed=j.executed(), truth=self.truth_dict(), seq=self._next_seq())

    def truth_dict(self) -> dict[str, Any]:
        t = self.truth
        return {"map": t.name, "rows": format_rows(t.free),
                "robots": {str(r): list(c) for r, c in sorted(t.starts.items())},
                "goals": [list(g) for g in t.goals],
                "connectivity": self.cfg.connectivity, "cell_size_m": self.cfg.cell_size_m,
                "slips": list(self.judge.skids), "safety_stops": self.judge.safety_stops,
                "vehicle": self.vehicle_dict(),
                "camera_component": self.mavlink_camera.record() if self.mavlink_camera is not None else None}

    def vehicle_dict(self) -> dict[str, Any] | None:
        """What the simulated autopilot itself saw: independent of what the UAV agent reports."""
        if self.follower is not None:
            return self.follower.truth()
        v = self.vehicle
        if v is None:
            return None
        state = v.landed_state
        return {"url": self.cfg.mavlink, "armed": v.armed, "landed_state": getattr(state, "name", str(state)),
                "max_altitude_m": round(v.max_altitude_m, 2), "bad_frames": v.bad_frames,
                "gcs": self.cfg.gcs, "refused_unsigned": v.refused_unsigned,
                "events": [[round(t, 2), text] for t, text in v.events]}

    def _on_camera(self, q: IncomingQuery) -> None:
        request = self._decode(q, CameraRequest)
        if request is None:
            return
        if request.calibration_only:   # no render: answered at once, ahead of images being made
            from .camera import calibration_frame

            _, view, model, _, estimator, t, seq, _ = self.exposure()
            q.reply(encode(calibration_frame(view, model, estimator, t, seq)))
            return
        # The shutter opens now, as the request arrives: the vehicle may fly on while the
        # image is rendered (tens to hundreds of milliseconds, off the transport's thread).
        try:
            from .camera import clip_roi

            shutter = time.monotonic()
            shot = self.exposure()
            roi = clip_roi(shot[2], request.roi_x, request.roi_y, request.roi_width, request.roi_height)
            self._camera_pool.submit(self._render_reply, q, (*shot, roi), shutter)
        except RuntimeError:  # shutting down
            q.finish()

    def _render_reply(self, q: IncomingQuery, shot: tuple, shutter: float | None = None) -> None:
        from .camera import capture_frame

        try:
            if shutter is not None:
                shot = self.at_shutter(shot, shutter)
            q.reply(encode(capture_frame(*shot)))
        except UavRobotsError as exc:
            self.warn(f"camera: {exc}")
            q.finish()
        except Exception as exc:  # noqa: BLE001 - a camera fault must not kill the world
            self.warn(f"camera failed: {type(exc).__name__}: {exc}")
            q.finish()

    def _start_camera_component(self) -> None:
        """The camera as a real drone's: a MAVLink camera component, its files over HTTP, its video."""
        c = self.cfg
        if not (c.camera_mavlink or c.camera_video):
            return
        from .camera import capture_frame
        from .camera.mavlink_camera import CameraLink, MavlinkCamera
        from .camera.stream import VideoStream, render_view, video_config

        video = (VideoStream(video_config(c.camera_video), self.camera_model, render_view(self.exposure), c.mavlink_bind)
                 if c.camera_video else None)
        self.mavlink_camera = MavlinkCamera(CameraLink(c.camera_mavlink, (c.home_lat, c.home_lon, c.home_alt_m),
                                                       bind_host=c.mavlink_bind),
                                            self.camera_model, self.exposure, lambda shot: capture_frame(*shot),
                                            self._camera_pool.submit, video)
        self.mavlink_camera.start()
        print(f"world: {self.mavlink_camera.describe()}", flush=True)

    def at_shutter(self, shot: tuple, shutter: float) -> tuple:
        """An exposure (`exposure()`'s) seen from the followed autopilot's pose at `shutter` (time.monotonic()
        when it opened), interpolated in its telemetry once the samples after it came (waited for here,
        off the transport's thread); a world that flies its own vehicle read its pose at the shutter."""
        if self.follower is None:
            return shot
        view = self.camera_view(shutter, wait_s=FOLLOW_WAIT_S)
        if view is None:
            raise UavRobotsError(f"no pose from the autopilot on {self.cfg.autopilot_pose} yet")
        return (shot[0], view, *shot[2:])

    def camera_view(self, at: float | None = None, wait_s: float = 0.0):
        """The camera's true pose and motion in the grid's NED frame: the vehicle's, lifted by the mount height.
        Following an autopilot: its pose at the instant `at` (now), None before it sent one."""
        from .camera import VehicleView
        if self.follower is not None:
            p = self.follower.pose_at(time.monotonic() if at is None else at, wait_s)
            if p is None:
                return None
            return VehicleView(p.north_m, p.east_m, p.down_m - self.cfg.camera_height_m, *p[3:])
        if self.vehicle is None:
            # No vehicle (tests of the services): a fixed camera over the centre that sees the whole floor.
            h, w = self.truth.free.shape
            c, m = self.cfg.cell_size_m, self.camera_model
            alt = 1.1 * max(w * c * m.fx / m.width, h * c * m.fy / m.height)
            return VehicleView(-h * c / 2, w * c / 2, -alt, 0.0)
        st = self.vehicle.state()
        n, e, d = st.pos
        return VehicleView(n, e, d - self.cfg.camera_height_m, st.yaw, st.roll, st.pitch, *st.vel)

    def capture(self):
        from .camera import capture_frame

        return capture_frame(*self.exposure())

    def exposure(self) -> tuple:
        """What one image shows, fixed at the shutter: the scene, the camera's true view and the
        clock; capture_frame's arguments."""
        from .camera import CameraModel, PoseEstimator, Scene, VehicleView

        if self.camera_model is None:   # never started (tests of capture alone)
            self.camera_model = CameraModel()
        if self.estimator is None:
            self.estimator = PoseEstimator(self.camera_model, self.cfg.seed)
        assert self.desk is not None
        with self.desk.cv:
            robots = dict(self.judge.positions)
        scene = Scene(self.truth.free, robots, list(self.truth.goals), self.landmarks,
                      goal_pads=bool(self.camera_model.goal_pads))
        view = self.camera_view()
        if view is None:   # no pose from the followed autopilot yet: the lens on the floor at its corner
            view = VehicleView(0.0, 0.0, -self.cfg.camera_height_m)
        scale = self.cfg.time_scale if self.follower is not None else 1.0   # simulated seconds, as the vehicle's
        t = self.vehicle.sim_time_s if self.vehicle is not None else (time.monotonic() - self._t0) * scale
        seed = self._next_seq()
        return scene, view, self.camera_model, self.cfg.cell_size_m, self.estimator, t, self._next_seq(), seed

    def _on_mission_end(self, key: str, payload: bytes) -> None:
        try:
            decode(payload, MissionEnd)
        except ProtocolError as exc:
            self.warn(f"{key}: {exc}")
            return
        if self.mission_ended is None:
            self.mission_ended = time.monotonic()

    def _on_robot_alive(self, key: str, alive: bool) -> None:
        rid = robot_id_from_key(key)
        if rid is not None and self.desk is not None:
            _send(self.desk.robot_alive(rid, alive))

    def _on_uav(self, _key: str, alive: bool) -> None:
        self.uav_alive = alive
        if alive:
            self.uav_seen = True
        elif self.mission_ended is None and self.uav_seen:
            self.finish("the UAV went away: mission aborted")


# ------------------------------------------------------------------ CLI
def add_world_parser(subparsers: Any) -> argparse.ArgumentParser:
    p = subparsers.add_parser("world", help="run the simulated world: floor, robots' physics, vehicle, camera",
                              description="Serve the simulated warehouse (moves, camera, record) on Zenoh "
                                          "and fly a simulated multicopter over MAVLink.")
    add_world_arguments(p)
    p.set_defaults(func=world_command)
    return p


# A 12 MP camera, as on common survey drones: it covers the 450x450 warehouse in 12
# images at 20 px per cell where a 1280x960 one needs 80 (and 80 flights between them).
DRONE_CAMERA = {"width": 4000, "height": 3000}


def add_world_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", default="warehouse-small",
                   help="a .map file, warehouse-small, warehouse-450, 'warehouse:blocks_x=..,blocks_y=..' "
                        "or 'random:width=..,height=..,density=..'")
    p.add_argument("--robots", type=int, default=8, help="number of robots (and goals)")
    p.add_argument("--seed", type=int, default=0, help="seed of the placement of robots and goals")
    p.add_argument("--scen", default=None, metavar="FILE", help="take starts and goals from a MovingAI .scen")
    p.add_argument("--fleet", default=DEFAULT_FLEET, help=f"fleet name: keys live under uavr/<fleet> (default {DEFAULT_FLEET})")
    add_session_arguments(p)
    p.add_argument("--mavlink", default=None, metavar="URL",
                   help=f"the vehicle's MAVLink link (pymavlink URL; default {DEFAULT_VEHICLE_URL}); 'none' runs "
                        "without a vehicle")
    add_ground_station_arguments(p)
    p.add_argument("--autopilot-pose", default=None, metavar="URL",
                   help="fly no vehicle: follow the autopilot whose telemetry comes on this link (its ground "
                        "station's port: `uav-robots vehicle --pose-link`, PX4 or ArduPilot SITL, a real drone) "
                        "and render the camera from its pose, e.g. udpin:127.0.0.1:14550")
    p.add_argument("--autopilot-origin", default=None, metavar="home|N,E,D",
                   help="with --autopilot-pose, where the autopilot's local frame lies: 'home' (default: its "
                        "first home is the floor's top-left corner) or its local origin's N,E,D on the floor "
                        "(metres; an indoor autopilot without GPS)")
    p.add_argument("--time-scale", type=float, default=1.0, metavar="X", help="simulated seconds per second")
    p.add_argument("--cell-size", type=float, default=1.0, metavar="M", help="grid cell size in metres")
    p.add_argument("--connectivity", type=int, choices=(4, 8), default=4)
    p.add_argument("--home", default=None, metavar="LAT,LON,ALT", help="the grid corner's geodetic position")
    p.add_argument("--camera", default="", metavar="[PRESET,]K=V,...",
                   help="the camera: a preset (ideal, realistic; default "
                        f"{DEFAULT_CAMERA_PRESET}) then keys over it, on the 12 MP drone camera (4000x3000, "
                        "90 deg), e.g. realistic,blur_sigma=2 or width=1280,height=960,noise_std=2 "
                        "(every key: docs/camera-and-perception.md)")
    p.add_argument("--camera-mavlink", default=None, metavar="URL",
                   help="also a MAVLink camera component (Camera Protocol v2) on a link of its own, e.g. "
                        "udpout:127.0.0.1:14560; its images served over HTTP on --mavlink-bind")
    p.add_argument("--camera-video", default=None, metavar="udp://HOST:PORT[?fps=F&width=W]",
                   help="stream the camera's video as H.264 over RTP to HOST:PORT (QGroundControl: 5600; "
                        "default 5 fps, 1280 px wide); off by default (it costs the world CPU)")
    p.add_argument("--fault", action="append", default=[], metavar="slip:P|skid:ROBOT@TICK",
                   help="slip:P: each move ends, with probability P, in another free neighbour cell or where "
                        "it started, and the robot is told it arrived (only a camera sees the truth); "
                        "skid:ROBOT@TICK: from tick TICK every move of that robot does so (a broken drive)")
    p.add_argument("--move-timeout", type=float, default=MOVE_BATCH_TIMEOUT_S, metavar="S",
                   help="how long a tick's moves are collected before the missing robots are made to stay")


WORLD_FAULTS = ("slip:", "skid:")   # the --fault kinds the world injects; the others are the robots'


def is_world_fault(spec: str) -> bool:
    return spec.strip().startswith(WORLD_FAULTS)


@dataclass(frozen=True)
class WorldFaults:
    slip: float = 0.0                                       # every move, with this probability
    skids: dict[int, int] = field(default_factory=dict)     # robot -> the tick from which every move skids


def world_faults(faults: list[str]) -> WorldFaults:
    """slip:P (any move ends elsewhere with probability P) and skid:ROBOT@TICK (from tick TICK every
    move of that robot ends elsewhere: a broken drive that keeps deviating); one line for a bad one."""
    slip, skids = 0.0, {}
    for f in faults:
        kind, _, value = f.strip().partition(":")
        if kind == "skid":
            robot, at, tick = value.partition("@")
            if not (robot.isdigit() and at and tick.isdigit() and int(tick) >= 1):
                raise UavRobotsError(f"--fault {f!r}: give skid:ROBOT@TICK (ticks start at 1)")
            skids[int(robot)] = int(tick)
            continue
        try:
            slip = float(value)
        except ValueError:
            slip = -1.0
        if kind != "slip" or not 0.0 <= slip <= 1.0:
            raise UavRobotsError(f"--fault {f!r}: the world takes slip:P with P in [0, 1] or skid:ROBOT@TICK")
    return WorldFaults(slip, skids)


def slip_probability(faults: list[str]) -> float:
    return world_faults(faults).slip


def _none(url: str | None) -> str | None:
    return None if url is None or url.lower() in ("none", "off", "") else url


def config_from_args(args: argparse.Namespace) -> WorldConfig:
    from .pose_follower import parse_origin

    home = parse_home(args.home) or HOME
    follow = _none(args.autopilot_pose)
    mav = _none(args.mavlink if args.mavlink is not None else (None if follow else DEFAULT_VEHICLE_URL))
    if follow and mav:
        raise UavRobotsError("with --autopilot-pose the world runs no vehicle: give --mavlink to the autopilot "
                             "(`uav-robots vehicle`)")
    if args.autopilot_origin is not None and not follow:
        raise UavRobotsError("--autopilot-origin places a followed autopilot: give --autopilot-pose URL too")
    camera_model_from(args.camera, DRONE_CAMERA)   # every value checked before anything starts
    faults = world_faults(args.fault)
    cfg = WorldConfig(fleet=args.fleet, map=args.map, robots=args.robots, seed=args.seed, scen=args.scen,
                      connectivity=args.connectivity, cell_size_m=args.cell_size, home_lat=home[0],
                      home_lon=home[1], home_alt_m=home[2], mavlink=mav, time_scale=args.time_scale,
                      camera={**DRONE_CAMERA, **camera_options(args.camera)}, connect=args.connect, listen=args.listen,
                      zenoh_config=args.zenoh_config, move_batch_timeout_s=args.move_timeout,
                      slip=faults.slip, skids=faults.skids, gcs=args.gcs, mavlink_key=args.mavlink_key,
                      mavlink_bind=args.mavlink_bind, camera_mavlink=_none(args.camera_mavlink),
                      camera_video=_none(args.camera_video), autopilot_pose=follow,
                      autopilot_origin=parse_origin(args.autopilot_origin))
    if cfg.camera_video:
        from .camera.stream import require_pyav, video_config
        video_config(cfg.camera_video)
        require_pyav()
    cfg.check()
    return cfg


def world_command(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    world = World(cfg)
    world.stop_on_signals()
    try:
        try:
            world.start()
        except MissionError:
            if world.stop.is_set():   # stopped while it was still looking for a router: not an error
                return 0
            raise
        print(f"world ready: {world.describe()}", flush=True)
        reason = world.run()
    finally:
        world.close()
    print(f"world: {reason or 'stopped'}; {world.judge.tick} ticks, {world.judge.collisions} collisions",
          flush=True)
    return 0
