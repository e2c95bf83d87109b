"""The world process: ground truth, the vehicle, the camera and the move service on Zenoh.

It owns what physically exists: the floor, where every robot stands, the goal
markers and the multicopter. It serves, under `uavr/<fleet>/world/`:
`info` (site calibration), `camera` (the image seen from the vehicle's current
pose), `move` (one tick's moves, judged together) and `record` (what happened,
for scoring); it also takes moves put ahead (`ahead/<ids>`, judged when the
UAV's Tick comes, answered on `judged/<ids>`: sim_world/ahead.py). It announces
`alive/world` once all of them are declared. The move desk is sim_world/desk.py, the
camera's part sim_world/camera_service.py, the process's options sim_world/cli.py.

    python -m sim_world --fleet F --connect tcp/127.0.0.1:7447 --robots 8
"""
from __future__ import annotations

import dataclasses
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from protocol.codec import decode, encode
from protocol.errors import ProtocolError, UavRobotsError
from protocol.keys import Keys, ids_of_ahead_key, ids_of_move_key, robot_id_from_key
from protocol.log import Throttled
from protocol.mapfile import format_rows
from protocol.messages import (MissionEnd, MoveAhead, MoveBatch, MoveBatchResult, MoveRequest, MoveResult, MovesJudged,
                               Record, RecordRequest, Tick, WorldInfo, WorldInfoRequest)
from protocol.process import Lifecycle
from protocol.transport import IncomingQuery, Transport, open_session
from scenarios.landmarks import LandmarkSet

from .ahead import AheadDesk
from .camera_service import WorldCamera
from .config import WorldConfig, fence_reach_m, vehicle_config
from .desk import Ask, MoveDesk, send_all
from .moves import MoveJudge
from .traffic import build_traffic
from .truth import build_truth


class World(WorldCamera, Lifecycle):
    def __init__(self, cfg: WorldConfig, transport: Transport | None = None) -> None:
        super().__init__()
        cfg.check()
        self.cfg = cfg
        self.keys = Keys(cfg.fleet)
        self.truth = build_truth(cfg)
        self.landmarks: LandmarkSet | None = None
        self.estimator: Any = None
        self.judge = MoveJudge(self.truth.free, dict(self.truth.starts), cfg.connectivity,
                               skid_prob=cfg.slip, skid_robots=dict(cfg.skids), seed=cfg.seed,
                               traffic=build_traffic(cfg.scene, self.truth.free, list(self.truth.starts.values()),
                                                     self.truth.goals, cfg.seed))
        self.desk: MoveDesk | None = None
        self.ahead: AheadDesk | None = None
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
        self._movers_thread: threading.Thread | None = None

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        cfg = self.cfg
        from .camera import CameraModel
        try:
            self.camera_model = CameraModel(**cfg.camera)
        except TypeError as exc:
            raise UavRobotsError(f"camera options: {exc}") from None
        from .camera import PoseEstimator, prepare, scene_landmarks
        self.landmarks = scene_landmarks(self.truth.free, cfg.cell_size_m, cfg.scene.landmark_spacing)
        self.estimator = PoseEstimator(self.camera_model, cfg.seed)
        # The lens and noise tables take seconds at 12 MP: built on the camera's thread while the
        # vehicle takes off, so the first image is not late; a world that stops leaves them unbuilt.
        self._camera_pool.submit(prepare, self.camera_model, self.stop.is_set)
        if cfg.autopilot_pose:
            from .pose_follower import PoseFollower
            self.follower = PoseFollower(cfg.autopilot_pose, cfg.autopilot_origin, cfg.mavlink_bind, self.warn).start()
        elif cfg.mavlink:
            from .vehicle import Vehicle
            self.vehicle = Vehicle(vehicle_config(cfg))
            # The geofence must not cut off part of a large floor: the farthest corner, with a margin.
            reach = fence_reach_m(self.truth.free.shape, cfg.cell_size_m)
            if reach > self.vehicle.param("GF_MAX_HOR_DIST"):
                self.vehicle.set_param("GF_MAX_HOR_DIST", reach)
            self.vehicle.start()
        if self.transport is None:
            c = self.cfg
            self.transport = open_session("world", c.listen, c.connect, c.zenoh_config, self.stop, alone="either")
        self.desk = MoveDesk(self.judge, cfg.move_batch_timeout_s, self.warn)
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
        if self.judge.traffic is not None:
            self._movers_thread = threading.Thread(target=self._publish_movers, name="movers", daemon=True)
            self._movers_thread.start()

    def _publish_movers(self, poll_s: float = 0.02) -> None:
        """The movers after each tick, for observers (a poll: the judge is pure, and a view or a
        recorder loses nothing by a tick merged into the next; the record keeps every tick)."""
        from protocol.messages import FloorMovers

        last = -1
        while not self.stop.wait(poll_s):
            assert self.desk is not None and self.judge.traffic is not None
            with self.desk.cv:
                tick = self.judge.tick
                movers = [(m.id, m.kind, m.cell) for m in self.judge.traffic.on_floor()] if tick != last else None
            if movers is None or self.transport is None:
                continue
            try:
                self.transport.put(self.keys.world_movers, encode(FloorMovers(tick, movers, seq=self._next_seq())))
            except Exception as exc:  # noqa: BLE001 - a closing session: the view misses a tick, nothing more
                self.warn(f"movers not published: {exc}")
            last = tick

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
        if self.camera_faults is not None:
            print(f"world: {self.camera_faults.summary()}", flush=True)
        if self.desk is not None:
            self.desk.close()
        if self._movers_thread is not None:
            self._movers_thread.join(timeout=1.0)
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
                **({"movers": {**self.judge.traffic.as_dict(), "collisions": self.judge.mover_collisions}}
                   if self.judge.traffic is not None else {}),
                "vehicle": self.vehicle_dict(),
                "camera_component": self.mavlink_camera.record() if self.mavlink_camera is not None else None,
                **({"camera_faults": {"unanswered": self.camera_faults.unanswered,
                                      "repeated": self.camera_faults.repeated}} if self.camera_faults else {})}

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
            send_all(self.desk.robot_alive(rid, alive))

    def _on_uav(self, _key: str, alive: bool) -> None:
        self.uav_alive = alive
        if alive:
            self.uav_seen = True
        elif self.mission_ended is None and self.uav_seen:
            self.finish("the UAV went away: mission aborted")
