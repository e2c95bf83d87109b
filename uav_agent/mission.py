"""The UAV's mission: take off -> survey -> perceive -> plan -> dispatch -> step -> land -> report.

A thin process around pure parts: `flight` (MAVLink), `perception` (OpenCV),
`planning` (assignment, paths, validator), `fleet` (the robots over Zenoh).
The UAV never reads the world's ground truth; it asks the world's record only
after the mission, to score it.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import secrets
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from protocol.codec import decode, encode
from protocol.errors import MissionError, PlanningError, ProtocolError
from protocol.grid import Cell
from protocol.keys import Keys
from protocol.messages import (PROTOCOL_VERSION, CameraFrame, MissionEnd, MissionEvent, MissionStatus,
                               Plan, Record, RecordRequest, Tick, WorldInfo, WorldInfoRequest)
from protocol.transport import Transport, open_session, zenoh_config

from .camera_source import CameraSource, CameraSourceConfig, open_camera_source
from .events import EventLog
from .fleet import FleetLink
from .pose_feed import PoseFeed
from .preview import Previewer
from .progress import Progress
from .watch import VehicleWatch

if TYPE_CHECKING:
    from .shots import Shots

QUERY_TIMEOUT_S = 10.0
CAMERA_TIMEOUT_S = 30.0    # a 12 MP image rendered on a loaded machine, or sent over a slow link
ABORT_LAND_TIMEOUT_S = 60.0
OBSERVER_WAIT_S = 5.0      # for the recorders the UAV was told of (MissionConfig.observers); then it goes on
# An autopilot may refuse to arm while it gets ready (ArduPilot SITL: about 38 s after it starts).
ARM_WAIT_S = 60.0
# A heading further than this from north after the first goto: the autopilot does not fly a goto's yaw.
HEADING_TOLERANCE_DEG = 3.0
LEVEL_TILT_DEG = 0.6       # a shutter (survey, fresh look, closer look) waits for the body, and its camera, this level ...
LEVEL_WAIT_S = 3.0         # ... for at most this long: a vehicle that has just braked hangs at its tilt limit
# An image whose own published attitude leans further is taken again: beyond the level the shutter
# accepts by four sigmas of a realistic attitude estimate (0.2 degrees), and about the most the
# survey's border absorbs (LEVEL_TILT_DEG's swing plus the hold tolerance's pixels).
RETAKE_TILT_DEG = 1.5
TELEMETRY_HZ = 50.0        # attitude, position and velocity asked of the autopilot (PX4's onboard link streams as fast)
STARTUP_LONGEST = 4         # robots still coming up extend the start-up wait, to this many times it
PLAN_RESEND_S = 2.0        # a plan not acknowledged within this is put again
SURVEY_BORDER_PX = 8       # pixels at each image's edge the survey never counts on, beyond the lens, tilt and hold
HOVER_TOLERANCE_M = 0.5    # a goto has arrived within this (Flight.goto's default)
HANDOFF_ALT_M = 10.0       # take-off to this height, clear of anything on the floor, then on to the first pose
SURVEY_SPEED_M_S = 20.0    # asked of the autopilot for the flight between hover poses (capped by MPC_XY_VEL_MAX)
MONITOR_FIRST = 25         # auto monitoring: the first image after this many ticks ...
MONITOR_SHARE = 0.2        # ... then whenever the images so far cost at most this share of execution time
PERCEPTION_WORKERS = 2     # survey images measured at once (OpenCV releases the GIL): a second core's worth
MAX_GLANCES = 3            # monitoring images perceived at once, off the tick loop (each holds a full frame)


@dataclass
class MissionConfig:
    fleet: str
    robots: int | None = None               # expected fleet size; None = as many as the camera sees
    listen: list[str] = field(default_factory=list)   # hub mode: be the Zenoh router
    connect: list[str] = field(default_factory=list)  # or join an existing router
    zenoh_config: str | None = None
    mavlink_url: str = "udpin://0.0.0.0:14540"
    planner: str | None = None
    assign: str = "optimal"
    connectivity: int = 4
    time_limit_s: float = 60.0
    fallback: bool = True
    seed: int = 0
    out: Path | None = None
    startup_timeout_s: float = 30.0
    observers: int = 0                 # wait (OBSERVER_WAIT_S at most) for this many recorders before the first status
    tick_timeout_s: float = 10.0
    tick_rate_hz: float = 0.0          # at most this many ticks per second (0: as fast as the fleet goes)
    monitor_every: int | None = None   # an image every this many ticks while robots move (0: never; None: auto)
    # A robot's marker module is 1/8 cell: 19 px per cell gives 2.4 px per module, which reads
    # through the realistic camera (at 17.5, 5 of the 450 warehouse's 50 robots went unread);
    # on the 450 floor with a 4000x3000 camera it is also where 3 x 3 images cover it, not 4 x 3.
    min_px_per_cell: float = 19.0
    camera: CameraSourceConfig = field(default_factory=CameraSourceConfig)   # where the images come from


class _Clock:
    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, phase: str) -> None:
        now = time.perf_counter()
        self.timings[phase] = round(self.timings.get(phase, 0.0) + now - self._t, 4)
        self._t = now


def _access_control(cfg: MissionConfig) -> bool:
    """Whether this UAV's router applies access control (`uav-robots run --secure`): a robot of protocol 1
    then cannot move, since it asks on the plain P/world/move (docs/protocol.md, Versioning)."""
    if not cfg.zenoh_config:
        return False
    from protocol.config import config_from_file
    return bool(json.loads(zenoh_config(config_from_file(cfg.zenoh_config)).get_json("access_control/enabled")
                           or "false"))


def _transport(cfg: MissionConfig) -> Transport:
    # Alone, the UAV joins a router already on this machine (a world started first) or becomes it.
    return open_session("uav", cfg.listen, cfg.connect, cfg.zenoh_config, alone="either")


def _query(transport: Transport, key: str, request: Any, reply_type: type, what: str,
           timeout_s: float = QUERY_TIMEOUT_S) -> Any:
    replies = transport.request(key, encode(request), timeout_s)
    if not replies:
        raise MissionError(f"no answer from the world's {what} within {timeout_s:g} s")
    try:
        return decode(replies[0], reply_type)
    except ProtocolError as exc:
        raise MissionError(f"the world's {what} answered garbage: {exc}") from None


EXIT_COMPLETED, EXIT_ABORTED, EXIT_DEGRADED = 0, 1, 3
# A robot named in this many repairs without a planned move it made between them keeps failing
# (deviating, stalling, erring): it is quarantined, out of the plan for good, not allowed to sink
# the others. A slipping robot fails now and then, and its moves between reset the count.
MAX_STRIKES = 3
# Repairs in a row that bring the fleet no nearer its goals (the repaired plan's lower bound is not
# below the best one since the working robots last changed): then the robots they named are quarantined.
MAX_FRUITLESS = 10
# After the plan's last tick, robots out of the plan whose session is still up (stalled, not lost)
# may come back; they show life only on a tick, so the fleet is ticked in place for this many tick
# timeouts, a tick every HOLD_TICK_S.
REJOIN_HOLD_TIMEOUTS = 2.0
HOLD_TICK_S = 0.1
DONE_WAIT_S = 5.0          # after the last tick: how long the Done flags may take to arrive
STOP_LAND_TIMEOUT_S = 10.0  # stopped by a signal or left by the world: the landing is bounded by this


@dataclass
class _Glance:
    """A monitoring image, perceived off the tick loop, and what it shows once it is."""
    plan_id: str
    tick: int
    shots: "Shots | None" = None
    off: list[int] | None = None       # robots off their planned cell at `tick`; None until judged
    on_plan: list[int] = field(default_factory=list)   # robots on their planned cell at `tick`
    on_goal: list[int] = field(default_factory=list)   # robots on their goals after their last move
    took: float = 0.0                  # wall seconds from the request to the judgement


@dataclass
class PlanState:
    """The plan the fleet executes now: robot r is at paths[r][i] at tick start_tick + i."""
    plan_id: str
    start_tick: int
    paths: dict[int, list[Cell]]
    goals: dict[int, Cell]

    @property
    def ids(self) -> list[int]:
        return sorted(self.paths)

    @property
    def end_tick(self) -> int:
        return self.start_tick + max(len(p) for p in self.paths.values()) - 1

    def cell(self, robot: int, tick: int) -> Cell:
        path = self.paths[robot]
        return tuple(path[min(max(tick - self.start_tick, 0), len(path) - 1)])


class Mission:
    def __init__(self, cfg: MissionConfig, progress: Progress | None = None) -> None:
        self.cfg = cfg
        self.keys = Keys(cfg.fleet)
        self.progress = progress or Progress()
        self.clock = _Clock()
        self.seq = 0
        self.report: dict[str, Any] = {"format": "uav-robots-report/1", "completed": False}
        self.uav: dict[str, Any] = {"mavlink_url": cfg.mavlink_url, "armed": False,
                                    "max_altitude_m": 0.0, "hover": None, "landed": False}
        self.frames: list[CameraFrame] = []
        self.events = EventLog()
        self._secured = _access_control(cfg)    # a robot of protocol 1 cannot move: refused
        self._older_said: set[int] = set()       # robots of an older protocol, said once each
        self.tick = 0                           # the last tick sent
        self.replans = 0
        self.monitored = 0
        self._glances: list[_Glance] = []       # monitoring images being perceived, oldest first
        self._monitor_work = 0.0                # wall seconds the monitoring images took, off the tick loop
        self.blocked: dict[int, Cell] = {}      # robots out of the plan (lost, stalled, faulty) -> their cell
        self.blocked_at: dict[int, float] = {}  # when each was taken out (a later sign of life brings it back)
        self.out_reason: dict[int, str] = {}    # why each robot out of the plan is out
        self.quarantined: dict[int, str] = {}   # robots out for good (they kept failing, or had no goal left)
        self.strikes: dict[int, list[str]] = {}  # robot -> its faults since it was last shown on its plan ("deviation@9")
        self._clean_moves: dict[int, int] = {}    # robot with strikes -> planned moves kept in a row since
        self._fruitless = 0                     # repairs in a row that brought the fleet no nearer its goals
        self._best_lb: tuple[frozenset[int], float] | None = None   # (working robots, best lower bound)
        self._fruitless_culprits: set[int] = set()
        self.verified: dict[int, bool] = {}
        self.confirmed: dict[int, str] = {}     # robot -> the plan under which an image after its last move showed it on its goal
        self._stops: list = []                  # arrival_tour.Stop: poses still to shoot for arrivals ...
        self._stop = None                       # ... and the one the vehicle flies to or holds at
        self._arrived_at: int | None = None     # the attitude sample current when the vehicle was seen at it
        self._arrivals: dict[int, int] = {}     # robot -> the tick of its last move in the plan flown
        # The vehicle's speed from pose to pose in wall time, stopping and levelling included:
        # measured by the survey, then by each hop between arrival stops.
        self._fly_m_s = SURVEY_SPEED_M_S
        self._flown_m = self._flown_s = 0.0
        self._hop: tuple[float, float] | None = None
        self._contradicted: set[int] = set()
        self.unserved: list[Cell] = []
        self.plan: PlanState | None = None
        self.goal_of: dict[int, Cell] = {}      # each robot's goal in the last plan it was part of
        self.first_result = None
        self.model = None
        self.watch: VehicleWatch | None = None
        self.pose_feed: PoseFeed | None = None
        self.camera: CameraSource | None = None   # camera_source: the world's query, MAVLink's camera or a video stream
        self._interpreter = None                # interpreted.InterpretedPlanner started ahead on a fresh clone
        self._heading = 0.0                     # the vehicle's kept heading when it flies no goto's yaw
        self._ended = False

    # ------------------------------------------------------------ helpers
    def _next(self) -> int:
        self.seq += 1
        return self.seq

    def _status(self, phase: str, **kw: Any) -> None:
        self.transport.put(self.keys.mission_status, encode(MissionStatus(phase=phase, seq=self._next(), **kw)))
        if phase != "executing":
            self.progress.phase(phase, kw.get("message", ""))

    def _track_altitude(self) -> None:
        north, east, down = self.flight.position_ned()
        self.uav["max_altitude_m"] = round(max(self.uav["max_altitude_m"], -down), 2)

    def _capture(self, calibration_only: bool = False) -> CameraFrame:
        frame = self.camera.frame(calibration_only)
        if frame.png:
            self._took(frame)
        return frame

    def _telemetry_pose(self) -> tuple[float, float, float, float, float, float]:
        """(north, east, down, yaw, roll, pitch) from the autopilot: a video frame's pose."""
        if self.flight is None:
            raise MissionError("no autopilot yet")
        north, east, down, yaw = self.flight.pose()
        roll, pitch, _ = self.flight.attitude_rad()
        return north, east, down, yaw, roll, pitch

    def _took(self, frame: CameraFrame) -> None:
        self.frames.append(frame)
        self.previewer.submit(frame)

    def _fusion(self, known: set[int] | None = None):
        from .perception import Fusion

        return Fusion(self.info.width, self.info.height, self.info.cell_size_m, known_ids=known,
                      landmarks=self.landmarks)

    def _shots(self, fusion, measure=None, whole=None, roi=None) -> "Shots":
        """Images asked for on the move, perceived as they arrive: measured (by `measure`, else
        `fusion.measure`, frames at once) and merged into `fusion` in order, or each handed
        whole to `whole`, which perceives it itself; only the sensor's region `roi`, if given."""
        from .shots import Shots

        return Shots(lambda: self.camera.start(roi), self._took, whole or measure or fusion.measure, CAMERA_TIMEOUT_S,
                     fence=self.camera.fence,
                     merge=None if whole else fusion.merge, workers=PERCEPTION_WORKERS,
                     max_tilt_rad=math.radians(RETAKE_TILT_DEG))

    def _budget(self, poses, what: str) -> None:
        """Fly `poses` only if the battery holds them and the landing after, with a reserve."""
        from .budget import flight_seconds, shortfall

        n, e, d = self.flight.position_ned()
        why = shortfall(self.flight.battery_time_left_s, flight_seconds(list(poses), (n, e, -d)), what,
                        self.flight.battery_pct)
        if why:
            raise MissionError(why)

    def _tour(self, poses, fusion) -> None:
        """Fly over `poses` (north, east, alt), taking an image at each without waiting for it;
        every image is perceived into `fusion` by the time this returns."""
        self._budget(poses, f"a look of {len(poses)} image(s)")
        shots = self._shots(fusion)
        try:
            for north, east, alt in poses:
                self.flight.goto(north, east, alt)
                self._hold_level()
                shots.shoot((north, east, alt))
            shots.drain()
        finally:
            shots.close()
        self._retake(shots, fusion)

    def _retake(self, shots, fusion) -> None:
        """Take again, holding still until each arrives, the images the vehicle flew away from
        or shot leaning."""
        if shots.missed:
            self._event("retake", [], f"{len(shots.missed)} image(s) not used: " + "; ".join(
                f"{why} at ({n:.1f}, {e:.1f}, {a:.1f})" for why, (n, e, a) in zip(shots.why_missed, shots.missed)),
                "holding still over each pose for a new image")
        for north, east, alt in shots.missed:
            self.flight.goto(north, east, alt)
            self._hold_level()
            fusion.add(self._capture())
        if shots.missed:
            self.uav["retaken_images"] = self.uav.get("retaken_images", 0) + len(shots.missed)
            self.flight.goto(*self._hover_ned)

    def _event(self, kind: str, robots, what: str, action: str = "") -> None:
        e = self.events.add(self.tick, kind, list(robots), what, action)
        try:   # for observers; the event log (report.json) is the record
            self.transport.put(self.keys.mission_event, encode(MissionEvent(
                tick=e.tick, time_s=e.time_s, kind=kind, robots=list(e.robots), what=what, action=action,
                seq=self._next())))
        except Exception:  # noqa: BLE001 - an abort's event must not be lost to a closing session
            pass
        self.progress.phase("event", f"tick {e.tick}: {kind} {list(e.robots) or ''} {what}"
                                     + (f" -> {action}" if action else ""))

    def _vehicle_fault(self, why: str) -> None:
        self._event("vehicle", [], why, "the mission stops")

    def _check_vehicle(self) -> None:
        if self.watch is not None and self.watch.fault:
            raise MissionError(f"vehicle: {self.watch.fault}")
        if self.fleet.world_gone:
            raise MissionError("the world went away (its alive/world token vanished): nobody judges the "
                               "robots' moves or renders the camera")

    # ------------------------------------------------------------ phases
    def run(self) -> dict[str, Any]:
        from .flight import Flight

        self.transport = _transport(self.cfg)
        self.flight = None
        try:
            self._token = self.transport.announce(self.keys.alive_uav)
            self.previewer = Previewer(lambda f: self.transport.put(self.keys.uav_frame, encode(f)))
            self.fleet = FleetLink(self.transport, self.keys, self.cfg.robots)
            self._await_observers()
            # Listening on MAVLink while the world starts: its vehicle's first heartbeat is not lost.
            self.flight = Flight(self.cfg.mavlink_url).open()
            self._status("connecting", message="waiting for the world on Zenoh")
            self.fleet.wait_until(lambda: self.fleet.world_alive, self.cfg.startup_timeout_s,
                                  lambda: f"no world on fleet {self.cfg.fleet} within {self.cfg.startup_timeout_s:g} s")
            info = _query(self.transport, self.keys.world_info, WorldInfoRequest(seq=self._next()), WorldInfo, "info")
            _check_floor(info)
            self.info = info
            from .perception import Landmarks
            self.landmarks = Landmarks.from_info(info)
            self.camera = open_camera_source(self.cfg.camera, self.transport, self.keys, info, self._next,
                                             self._telemetry_pose, self.cfg.startup_timeout_s)
            self.uav["camera_source"] = self.cfg.camera.kind
            self._camera = self._capture(calibration_only=True)   # the camera's intrinsics and lens
            self.frames.clear()
            # The survey's image border needs the lens's full-frame undistortion maps (0.4 s at
            # 12 MP, which the first image's perception then reuses): worked out while the
            # autopilot link comes up, not between arming and the take-off.
            lens = ThreadPoolExecutor(1, thread_name_prefix="lens-border")
            self._survey_border = lens.submit(self._border, self._camera, self.cfg.min_px_per_cell,
                                              self.info.cell_size_m)
            lens.shutdown(wait=False)
            from .planning.warm import is_warm
            self._compiling = not is_warm()   # a fresh clone: the kernels compile during the flight
            self._skip_warm = threading.Event()
            self._warm = threading.Thread(target=self._warm_up_planner, name="planner-warm-up", daemon=True)
            self._warm.start()
            self.flight.connect(timeout_s=self.cfg.startup_timeout_s)
            for refused in self.flight.stream(TELEMETRY_HZ):
                self.progress.phase("connect", f"the autopilot keeps its own rate for {refused}")
            self.uav["frame"] = "local" if self.flight.local_frame else "global"   # indoor: no home, offboard
            self.uav["autopilot"] = self.flight.autopilot   # PX4, ARDUPILOT, ...: from its heartbeat
            self.watch = VehicleWatch(self.flight, self._vehicle_fault)
            # Every command and every wait of the flight checks it, and every wait for the fleet: the
            # autopilot's own decision wins, and it is noticed within a poll in every phase.
            self.flight.guard = lambda: self.watch.fault
            self.fleet.interrupt = lambda: f"vehicle: {self.watch.fault}" if self.watch.fault else None
            self.pose_feed = PoseFeed(self.flight, lambda p: self.transport.put(self.keys.uav_pose, encode(p)),
                                      t0=self.events.t0)
            self.clock.lap("connect")
            if self._compiling:
                from .planning.interpreted import InterpretedPlanner
                # its interpreter and imports while the vehicle climbs (the link's set-up before
                # took its CPU: the connection came 0.6 s later)
                self._interpreter = InterpretedPlanner()

            self._fly_and_survey()
            model = self.model = self._perceive()
            result = self.first_result = self._plan(model)
            self._dispatch(PlanState(secrets.token_hex(4), 0, dict(zip(self.ids, map(list, result.paths))),
                                     dict(zip(self.ids, result.goals))), first=True)
            while True:
                self._execute()
                self._verify()
                self._drop_the_gone()
                back, off = self._rejoining(), self._off_goal()
                if not back and not off:
                    break
                self._recover(self.tick, {"rejoin": back, "deviation": off})
            self._check_vehicle()
            self.watch.expect_airborne(False)
            self._end(self._outcome() != "failed", self._reason())
            self._land()
            self._finish_report()
            return self.report
        except Exception as exc:
            # A failed mission must not leave the drone hovering armed: land it, then report the failure.
            why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._event("abort", [], why, "ended the mission; " + self._abort_course())
            try:
                self._end(False, why)   # the robots and observers hear why, not just "aborted"
            except Exception:  # noqa: BLE001 - the session may be what failed
                pass
            self._abort_landing()
            self._abort_report(str(exc))
            raise
        except BaseException as exc:   # SIGTERM (protocol.process unwinds it as SystemExit) or SIGINT
            self._stopped(exc)
            raise
        finally:
            if not self._ended:
                try:
                    self._end(False, "mission aborted")
                except Exception:  # noqa: BLE001 - the session may already be gone
                    pass
            if self.watch is not None:
                self.watch.close()
            if self.pose_feed is not None:
                self.pose_feed.close()
            if self.camera is not None:
                self.camera.close()
            if self.flight is not None:
                self.flight.close()
            if hasattr(self, "fleet"):
                self.fleet.close()
            if self._interpreter is not None:
                self._interpreter.close()
            self.transport.close()
            self.progress.close()

    def _await_observers(self) -> None:
        """A recorder started beside the UAV connects once the UAV listens; whatever the UAV publishes
        before that is lost to it (Zenoh keeps no history), the take-off included."""
        n = self.cfg.observers
        if n <= 0:
            return
        try:
            self.fleet.wait_until(lambda: len(self.fleet.observers) >= n, OBSERVER_WAIT_S,
                                  lambda: f"{len(self.fleet.observers)} of {n} observer(s) within {OBSERVER_WAIT_S:g} s")
        except MissionError as exc:
            self.progress.phase("connecting", f"not waiting longer for a recorder ({exc}): it may miss the start")

    def _warm_up_planner(self) -> None:
        from .planning import warm
        from .planning.pipeline import warm_up
        from .planning.registry import DEFAULT_PLANNER

        try:
            # A cold cache is compiled by a process of its own (the launcher's, else one started
            # here): compiling on this thread would hold the GIL through the survey.
            if self._compiling:
                warm.start(self.cfg.planner, self.cfg.connectivity)
            with warm.kernel_lock():
                if not self._skip_warm.is_set():   # planned without them: loading now would only stall
                    warm_up(self.cfg.planner or DEFAULT_PLANNER, self.cfg.connectivity)
        except Exception:  # noqa: BLE001 - the real plan call reports any problem properly
            pass

    def _fly_and_survey(self) -> None:
        from .survey import path_length, survey_poses

        self._status("takeoff", message=f"arming and climbing over MAVLink ({self.cfg.mavlink_url})")
        self.flight.arm(ARM_WAIT_S, on_wait=lambda why: self.progress.phase(
            "takeoff", f"the autopilot is not ready to arm yet, asking again: {why}"))
        self.uav["armed"] = True
        first = self._camera
        poses = self._poses = survey_poses(self.info.width, self.info.height, self.info.cell_size_m, first,
                                           min_px_per_cell=self.cfg.min_px_per_cell,
                                           border_px=self._survey_border.result())
        self.pose_feed.flying(True)
        # A take-off climbs straight up (PX4's does); the rest of the climb is flown on the way to
        # the first pose, the vehicle climbing and crossing at once.
        # Watched from the climb on: a failsafe or a ground station may take the vehicle at once.
        self.watch.expect_airborne(True, taking_off=True)
        self.flight.takeoff(min(poses[0][2], HANDOFF_ALT_M))
        # In the air, the autopilot's estimate is of a hover's draw, not the ground's.
        self._budget(poses, f"the survey of {len(poses)} image(s)")
        try:
            self.flight.set_speed(SURVEY_SPEED_M_S)
        except MissionError as exc:   # an autopilot without DO_CHANGE_SPEED flies its cruise speed
            self.progress.phase("survey", f"keeping the vehicle's cruise speed: {exc}")
        self.flight.goto(*poses[0])
        poses = self._poses = self._turned_survey(poses)
        self._track_altitude()
        self.clock.lap("takeoff")
        # The images are perceived while the vehicle flies on. The first one also measures the
        # camera's blur: if the survey's height is too high to read markers through it, the
        # poses still ahead are dropped for a lower survey.
        self.survey_fusion = self._fusion()
        verdict: dict[str, Any] = {}
        t_survey = time.perf_counter()

        judging = threading.Lock()

        def measure(frame: CameraFrame):   # on the images' threads, the fusion merges in order
            from .perception.frames import pixels

            seen = pixels(frame)        # decoded and undistorted once, for the blur check and the fusion
            with judging:
                judge = "judged" not in verdict
                verdict["judged"] = True
            if judge:
                verdict["lower"] = self._sharp_enough(seen.gray, first)
            return self.survey_fusion.measure(seen)

        shots = self._shots(self.survey_fusion, measure)
        try:
            for i, (north, east, alt) in enumerate(poses):
                if verdict.get("lower") is not None:
                    break
                self._status("survey", message=f"image {i + 1}/{len(poses)} from {alt:.1f} m")
                self.flight.goto(north, east, alt)
                self._track_altitude()
                self._hold_level()
                shots.shoot((north, east, alt))
            shots.drain(first=1)
            lower = verdict.get("lower")
            if lower is not None:   # the first image was too blurred for the planned height: the lower survey
                poses = self._poses = lower
                for i, (north, east, alt) in enumerate(poses):
                    self._status("survey", message=f"image {i + 1}/{len(poses)} from {alt:.1f} m "
                                                    "(lower: blurred camera)")
                    self.flight.goto(north, east, alt)
                    self._track_altitude()
                    self._hold_level()
                    shots.shoot((north, east, alt))
            # Hover over the floor's centre while the robots move: the leader keeps them in view.
            c = self.info.cell_size_m
            centre_n, centre_e = -self.info.height * c / 2, self.info.width * c / 2
            hover_alt = self._survey_alt = max(p[2] for p in poses)
            self._hover_ned = (centre_n, centre_e, hover_alt) if len(poses) > 1 else poses[-1]
            # Perception's backlog is the survey's only wait: the vehicle flies on to the hover
            # meanwhile, and through perception, planning and dispatch (it must be there only when
            # the robots start moving, see `_reach_hover`).
            self.flight.go(*self._hover_ned)
            shots.drain()
        finally:
            shots.close()
        self._retake(shots, self.survey_fusion)
        took = time.perf_counter() - t_survey
        if took > 0:
            self._flown_m, self._flown_s = path_length(poses, poses[0][:2]), took
            self._fly_m_s = max(1.0, self._flown_m / took)
        self.clock.lap("survey")

    def _sharp_enough(self, gray, camera: CameraFrame):
        """None if the survey's resolution reads markers through the blur of this (undistorted,
        grey) image; else the survey poses at the resolution that does (measured from the image's
        own edges)."""
        from .perception.blur import blur_sigma
        from .survey import ROBOT_MODULE_CELLS, heading_border, px_per_cell_for, survey_poses

        sigma = blur_sigma(gray)
        c = self.info.cell_size_m
        module = ROBOT_MODULE_CELLS if self.landmarks is None else min(ROBOT_MODULE_CELLS, self.landmarks.module_m / c)
        need = px_per_cell_for(sigma, self.cfg.min_px_per_cell, module)
        self.uav["survey_blur_px"] = round(sigma, 2)
        if need <= self.cfg.min_px_per_cell:
            return None
        self.uav["survey_px_per_cell"] = round(need, 1)
        self.progress.phase("survey", f"the camera blurs by {sigma:.1f} px: surveying at {need:.0f} px per cell "
                                      f"instead of {self.cfg.min_px_per_cell:g}")
        return survey_poses(self.info.width, self.info.height, c, camera, min_px_per_cell=need,
                            border_px=heading_border(camera, self._border(camera, need, c), self._heading))

    def _turned_survey(self, poses):
        """The survey's poses again if the autopilot kept another heading than the goto's north (ArduCopter
        ignores a goto's yaw): the footprints are turned, so each tile is what a turned image surely holds."""
        from .survey import heading_border, survey_poses

        heading = math.remainder(self.flight.pose()[3], 2 * math.pi)
        if abs(heading) <= math.radians(HEADING_TOLERANCE_DEG):
            return poses
        self._heading = heading
        turned = survey_poses(self.info.width, self.info.height, self.info.cell_size_m, self._camera,
                              min_px_per_cell=self.cfg.min_px_per_cell,
                              border_px=heading_border(self._camera, self._survey_border.result(), heading))
        self.uav["heading_kept_deg"] = round(math.degrees(heading), 1)
        self.progress.phase("survey", f"the autopilot keeps its heading of {math.degrees(heading):.0f} deg (a "
                                      f"goto's yaw is not flown): {len(turned)} turned footprint(s) instead of "
                                      f"{len(poses)}")
        return turned

    @staticmethod
    def _border(camera: CameraFrame, px_per_cell: float = MissionConfig.min_px_per_cell,
                cell_size_m: float = 1.0) -> tuple[int, int]:
        """Pixels (left and right, top and bottom) of each image the survey does not count on:
        where the lens leaves the undistorted image empty; how far a tilt the shutter accepts
        (LEVEL_TILT_DEG: a body-fixed camera, a hover wobble) swings the footprint's edges
        (`survey.tilt_margin_px`, at any altitude); and how far the vehicle may hold from its
        pose (the hover tolerance, sideways and in height: about as many pixels as it is metres
        times the survey's pixels per metre, each)."""
        from .perception.frames import lens_margin_px
        from .survey import tilt_margin_px

        tilt = tilt_margin_px(camera, math.radians(LEVEL_TILT_DEG))
        base = SURVEY_BORDER_PX + lens_margin_px(camera) + math.ceil(2 * HOVER_TOLERANCE_M * px_per_cell / cell_size_m)
        return base + tilt[0], base + tilt[1]

    def _perceive(self):
        # The robots on the network name the ids the camera may see; a marker read as any
        # other id is a misread, not a robot.
        expected = self.cfg.robots
        if expected is not None:
            wait = self.cfg.startup_timeout_s
            self.fleet.wait_until(lambda: len(self.fleet.alive) >= expected, wait,
                                  lambda: f"only {len(self.fleet.alive)} of {expected} robots came alive "
                                          f"(none more for {wait:g} s): robots "
                                          f"{sorted(set(range(expected)) - self.fleet.alive)[:10]} missing",
                                  progress=lambda: len(self.fleet.alive), longest=STARTUP_LONGEST * wait)
        with self.fleet.cv:
            known = set(self.fleet.alive) or None
        from .perception.verdict import raise_if_missing

        self._status("perceive", message=f"{len(self.frames)} image(s) through OpenCV")
        self.survey_fusion.known_ids = known
        model = self._see(self.survey_fusion)
        self.perception_warnings = model.warnings
        self.perception_frames = model.frames
        raise_if_missing(model, known, expected)
        self.clock.lap("perceive")
        return model

    def _see(self, fusion, for_map: bool = True, expected: set[int] | None = None):
        """The model of what `fusion` holds; what it leaves in doubt gets closer looks: markers
        whose id did not decode, unsure cells (before they are taken for obstacles), cells no image
        saw, and, when fewer goals than robots were seen, the robots (one may stand on a goal and
        hide most of it). Every doubtful cell is planned for; the hovers per round are capped.
        `expected`: the robots whose absence is a doubt (default the fusion's known robots: a
        verification's look over some goals does not miss the robots confirmed elsewhere, and
        on a floor of lone obstacles each would cost a round of closer looks)."""

        from .perception.relook import ROUNDS, plan_round

        known = fusion.known_ids if expected is None else expected
        model = fusion.model()
        for attempt in range(1, ROUNDS + 1):
            here = self.flight.position_ned()
            targets, hovers = plan_round(model, known, for_map, attempt, self._survey_alt, self.info.cell_size_m,
                                         self._camera, self.landmarks, (here[0], here[1]),
                                         math.radians(LEVEL_TILT_DEG), len(self._poses))
            if not targets:
                break
            heights = sorted({round(alt, 1) for _, _, alt in hovers})
            # An event, not only a progress line: a closer look costs seconds, and the report says why.
            missing = sorted(set(known or ()) - set(model.robots))
            self._event("closer-look", missing,
                        f"{len(targets)} cell(s) in doubt: {model.unseen} unseen, {len(model.unidentified)} unreadable "
                        f"marker(s){f' at {model.unidentified[:5]}' if model.unidentified else ''}, {len(model.unsure)} "
                        f"unsure{f' at {model.unsure[:5]}' if model.unsure else ''}, {len(model.robots)} robots / "
                        f"{len(model.goals)} goals seen",
                        f"{len(hovers)} hover(s) at {heights} m (round {attempt})")
            self._tour(hovers, fusion)
            model = fusion.model()
            self.flight.goto(*self._hover_ned)
        return model

    def _hold_level(self) -> None:
        """Wait, briefly, for the airframe to level out: a camera fixed to the body sees the floor
        through its tilt, and a vehicle that has just stopped still leans by up to its tilt limit
        (20 degrees swings an image's footprint by a third of the altitude)."""

        deadline = time.monotonic() + LEVEL_WAIT_S
        arrived = self.flight.attitude_sample()[3]
        while time.monotonic() < deadline and not self._level_since(arrived):
            time.sleep(0.02)

    def _level_since(self, arrived: int) -> bool:
        """Level by an attitude sample sent after `arrived` (the time of the one current when the
        vehicle was seen to arrive; 0 from an autopilot that times none). The one read with the
        arrival may have been sent before it, while the vehicle cruised level at constant speed:
        only a later one shows it braking (a survey image was shot leaning 20 degrees)."""
        roll, pitch, _, stamp = self.flight.attitude_sample()
        return (stamp != arrived or not stamp) and math.hypot(roll, pitch) <= math.radians(LEVEL_TILT_DEG)

    def _look(self, cells: list[Cell] | None = None, back: bool = True,
              expected: set[int] | None = None) -> dict[int, Cell]:
        """A fresh look from the survey poses, at the whole floor or only at the poses that
        see `cells`, then `back` to the hover: robot id -> the cell the camera sees it on.
        `expected`: the robots the look is for (default every robot); only their absence calls
        for closer looks."""
        from .arrival_tour import Stop, route
        from .survey import covering, nearer_end_first

        here = self.flight.position_ned()
        if cells is None:   # the whole survey: its lawn-mower order is the short one
            poses = nearer_end_first(self._poses, (here[0], here[1]))
        else:
            held = covering(self._poses, cells, self.info.cell_size_m)
            poses = [s.pose for s in route([Stop(p, 0, frozenset()) for p in held], (here[0], here[1]),
                                           0, 0.0, self._fly_m_s)]
        fusion = self._fusion(set(self.ids))
        self._tour(poses, fusion)
        if back:
            self.flight.goto(*self._hover_ned)
        model = self._see(fusion, for_map=False, expected=expected)
        return {r: tuple(c) for r, c in model.robots.items()}

    def _plan(self, model):
        from .planning.registry import DEFAULT_PLANNER

        ids = sorted(model.robots)
        planner = self.cfg.planner or DEFAULT_PLANNER
        starts = [model.robots[i] for i in ids]
        options = dict(planner=planner, assign=self.cfg.assign, connectivity=self.cfg.connectivity,
                       time_limit=self.cfg.time_limit_s, fallback=self.cfg.fallback, seed=self.cfg.seed)
        self._status("plan", message=f"{len(ids)} robots, planner {planner}, assignment {self.cfg.assign}")
        try:
            result = self._plan_mission(model.free, starts, list(model.goals), **options)
        except PlanningError:
            from .perception.verdict import explain_unplannable

            # Robots or goals walled in by what the camera read as shelf: a perception failure.
            why = explain_unplannable(model, self.cfg.connectivity)
            if why is not None:
                raise why from None
            raise
        for note in result.notes:
            self.progress.phase("plan", note)
        self.ids = ids
        self.model_free = model.free
        self.clock.lap("plan")
        return result

    def _plan_mission(self, free, starts, goals, **options):
        """`plan_mission`; on a fresh clone's first run, while the kernels still compile, the same
        planners interpreted (a repair's plan too: planned in the UAV's process, the compile held
        the fleet 48 s after a robot was lost), else once the compile is done."""
        from .planning.pipeline import plan_mission

        if self._compiling and self._warm.is_alive():
            result = self._plan_while_compiling(free, starts, goals, options)
            if result is not None:
                return result
            if self._warm.is_alive():
                self.progress.phase("plan", "compiling the planners (first run on this machine only, ~30 s; "
                                            "later runs load numba's cache; `uav-robots build` compiles them "
                                            "ahead of time instead)")
        self._warm.join()
        return plan_mission(free, starts, goals, **options)

    def _plan_while_compiling(self, free, starts, goals, options):
        """The plan by the same planners interpreted, while their kernels still compile (a fresh
        clone's first run): a few seconds for the missions `uav-robots run` flies (the 450x450
        warehouse's 50 robots: about 2 s, against half a minute's wait); None when the instance is
        too large for that or the interpreted run failed: the caller then waits for the kernels."""
        from .planning.interpreted import InterpretedPlanner, fits

        ahead, self._interpreter = self._interpreter, None   # the child started at takeoff serves once
        if not fits(free, len(starts), len(goals)):
            if ahead is not None:
                ahead.close()
            return None
        self.progress.phase("plan", "the planners' kernels are still compiling (first run on this machine "
                                    "only): planning this instance with them interpreted")
        planner = ahead or InterpretedPlanner()
        try:
            result = planner.plan(free, starts, goals, **options)
            self._skip_warm.set()
            return result
        except (PlanningError, RuntimeError) as exc:
            self.progress.phase("plan", f"interpreted planning failed ({str(exc).splitlines()[0]}); "
                                        "waiting for the compiled kernels")
            return None
        finally:
            planner.close()

    def _dispatch(self, plan: PlanState, first: bool = False) -> list[int]:
        """Check the plan, send it, wait for the acknowledgements; returns the robots that failed to take it."""
        from .planning.types import Problem
        from .planning.validator import check

        ids = plan.ids
        free = self.model_free.copy()
        for x, y in self.blocked.values():
            free[y, x] = False
        # The validator is independent of the planners: nothing unchecked leaves the UAV.
        check(Problem(free, [tuple(plan.paths[r][0]) for r in ids], [plan.goals[r] for r in ids],
                      self.cfg.connectivity), [plan.paths[r] for r in ids])
        if first:
            self._status("dispatch", message=f"waiting for {len(ids)} robots to be alive, then sending plans")
            self.fleet.wait_until(lambda: set(ids) <= self.fleet.alive, self.cfg.startup_timeout_s,
                                  lambda: f"robots {sorted(set(ids) - self.fleet.alive)[:10]} never came alive "
                                          f"within {self.cfg.startup_timeout_s:g} s")
        self.plan = plan
        self.goal_of.update(plan.goals)
        self._plan_stops(plan)
        pid = plan.plan_id
        acked = lambda r: self.fleet.acks.get(r) is not None and self.fleet.acks[r].plan_id == pid  # noqa: E731
        deadline = time.monotonic() + self.cfg.startup_timeout_s
        try:
            while True:
                # A plan put before a robot's subscriber was ready is lost; robots acknowledge a
                # resent plan again, so resending to the silent ones is safe.
                for rid in (r for r in ids if not acked(r)):
                    self.transport.put(self.keys.plan(rid), encode(Plan(
                        robot=rid, plan_id=pid, path=plan.paths[rid], goal=plan.goals[rid],
                        start_tick=plan.start_tick, connectivity=self.cfg.connectivity, seq=self._next())))
                try:
                    self.fleet.wait_until(lambda: all(acked(r) for r in ids),
                                          min(PLAN_RESEND_S, max(0.0, deadline - time.monotonic())),
                                          lambda: f"robots {[r for r in ids if not acked(r)][:10]} did not "
                                                  f"acknowledge plan {pid} within {self.cfg.startup_timeout_s:g} s",
                                          abort=lambda: self.fleet.lost_among(ids))
                    break
                except MissionError:
                    if time.monotonic() >= deadline or self.fleet.lost_among(ids):
                        raise
        except MissionError as exc:
            if first:
                raise
            self._event("dispatch", [r for r in ids if not acked(r)], str(exc))
        self._older_protocols([r for r in ids if acked(r)])
        with self.fleet.cv:
            failed = [r for r in ids if not acked(r) or not self.fleet.acks[r].ok]
        refused = [(r, self.fleet.acks[r].error) for r in failed if acked(r)]
        if refused and first:
            raise MissionError(f"robot {refused[0][0]} refused its plan: {refused[0][1]}")
        for r, why in refused:
            self._event("plan-refused", [r], why)
        if first:
            self._reach_hover()
            self.clock.lap("dispatch")
        return failed

    def _older_protocols(self, ids: list[int]) -> None:
        """Robots whose PlanAck states an older protocol (docs/protocol.md, Versioning): under access control
        refused, their ack made a refusal naming what they lack; otherwise served, said once per robot."""
        with self.fleet.cv:
            older = {r: self.fleet.acks[r].protocol for r in ids
                     if self.fleet.acks[r].ok and self.fleet.acks[r].protocol < PROTOCOL_VERSION}
            if self._secured:
                for r, version in older.items():
                    self.fleet.acks[r] = dataclasses.replace(self.fleet.acks[r], ok=False, error=(
                        f"robot {r} keeps protocol {version}: it asks its moves on P/world/move, which access "
                        f"control leaves unreachable; it needs protocol {PROTOCOL_VERSION} (docs/protocol.md, "
                        "Versioning)"))
                return
        for r, version in older.items():
            if r not in self._older_said:
                self._older_said.add(r)
                self._event("older-protocol", [r], f"robot {r} keeps protocol {version}: served, but it refuses a "
                            "repair that does not start where it believes it stands (it reads no start_tick)"
                            + (" and a diagonal step unless started with 8-connectivity (it reads no connectivity)"
                               if self.cfg.connectivity == 8 else ""),
                            "a repair it refuses takes it out of the plan")

    def _reach_hover(self) -> None:
        """Wait until the vehicle holds at the hover pose the survey sent it to; unless arrival
        stops are to be flown from the first tick on (a floor of several poses, whose hover
        sees only part of it): then the vehicle turns to the first stop from wherever it is."""
        n, e, alt = self._hover_ned
        if len(self._poses) == 1 or not self._stops:
            n, e, down = self.flight.goto(n, e, alt)
            alt = -down
            self._track_altitude()
        c = self.info.cell_size_m
        self.uav["hover"] = [round(e / c, 2), round(-n / c, 2), round(alt, 2)]

    def _execute(self) -> None:
        self._status("executing", tick=0, ticks=self.plan.end_tick, robots=len(self.ids), message="")
        self.progress.phase("execute", f"{self.plan.end_tick} ticks, {len(self.ids)} robots in lockstep")
        period = 1.0 / self.cfg.tick_rate_hz if self.cfg.tick_rate_hz > 0 else 0.0
        self._exec_t0, self._exec_k0 = time.perf_counter(), self.tick
        next_at = time.monotonic()
        hold_until: float | None = None
        while True:
            pace = period
            if self.tick >= self.plan.end_tick:
                hold_until = self._hold_for_rejoin(hold_until)
                if hold_until is None:
                    break
                pace = max(period, HOLD_TICK_S)
            self._check_vehicle()
            if pace:
                next_at += pace
                time.sleep(max(0.0, next_at - time.monotonic()))
            plan = self.plan
            k = self.tick = self.tick + 1
            with self.fleet.cv:   # a state for tick k is a robot's only once Tick(k) is out
                self.fleet.clock = max(self.fleet.clock, k)
            self.transport.put(self.keys.tick, encode(Tick(k=k, ticks=plan.end_tick, plan_id=plan.plan_id,
                                                           batch_states=True, seq=self._next())))
            faults = self.fleet.wait_tick(plan.ids, k, self.cfg.tick_timeout_s, interrupt=self._interrupted)
            self._check_vehicle()
            if not faults:
                with self.fleet.cv:
                    off = [r for r in plan.ids if self.fleet.cells.get(r) != plan.cell(r, k)]
                if off:
                    faults = {"deviation": off}
            if not faults:
                off = self._monitor_seen()
                if off:
                    faults = {"deviation": off}
                else:
                    self._look_between(k)
            if not faults:
                back = self._rejoining()
                if back:
                    faults = {"rejoin": back}
            if faults:
                self._recover(k, faults)
                next_at = time.monotonic()
                hold_until = None
            elif self.strikes:
                self._moved_cleanly(plan, k)
            done = sum(1 for r in plan.ids if self._done_for(r, plan))
            self.progress.ticks(k, self.plan.end_tick, done, len(plan.ids))
            if k % 10 == 0 or k == self.plan.end_tick:
                self.transport.put(self.keys.mission_status, encode(MissionStatus(
                    phase="executing", tick=k, ticks=self.plan.end_tick, done=done, robots=len(self.ids),
                    seq=self._next())))
        self._last_looks()
        self.ticks = self.tick
        self.clock.lap("execute")

    def _interrupted(self) -> bool:
        """A tick's wait ends early when the vehicle or the world fails (both end the mission)."""
        return (self.watch is not None and self.watch.fault is not None) or self.fleet.world_gone

    def _hold_for_rejoin(self, until: float | None) -> float | None:
        """After the plan's last tick: while robots out of the plan may still come back (their session
        is up: stalled, not lost), the fleet is ticked in place, until REJOIN_HOLD_TIMEOUTS tick
        timeouts have passed; a stall counted in ticks, or a robot frozen for a while, ends so. Returns
        when the hold ends (None: it is over, or nobody is waited for)."""
        with self.fleet.cv:
            waited = sorted(r for r in self.blocked if r in self.fleet.alive and r not in self.quarantined)
        if not waited:
            return None
        now = time.monotonic()
        if until is None:
            hold = REJOIN_HOLD_TIMEOUTS * self.cfg.tick_timeout_s
            self._event("hold", waited, "out of the plan, their sessions still up",
                        f"ticking the fleet in place for up to {hold:g} s for them to come back")
            return now + hold
        if now >= until:
            self._event("hold-over", waited, "did not come back", "the mission ends without them")
            return None
        return until

    def _forgive(self, robots) -> None:
        """Robots shown on their plan start afresh (an image, or two clean moves in a row)."""
        for r in robots:
            self.strikes.pop(r, None)
            self._clean_moves.pop(r, None)

    def _moved_cleanly(self, plan: PlanState, k: int) -> None:
        """A tick kept by every robot: those with strikes that made a planned move in it count it. A
        state alone proves nothing (a skidding drive tells its robot it arrived), but the world accepting
        the next move from the cell the robot believed proves the move before it: two in a row clear."""
        for r in [r for r in self.strikes if r in plan.paths and k > plan.start_tick
                  and plan.cell(r, k) != plan.cell(r, k - 1)]:
            self._clean_moves[r] = self._clean_moves.get(r, 0) + 1
            if self._clean_moves[r] >= 2:
                self._forgive([r])

    def _plan_stops(self, plan: PlanState) -> None:
        """Where to confirm the arrivals of `plan` while it runs. A confirmation under an earlier
        plan stands for a robot the new one leaves on its goal."""
        from .arrival_tour import arrival_ticks, stops

        self.confirmed = {r: plan.plan_id for r in self.confirmed if r in plan.paths
                          and {tuple(c) for c in plan.paths[r]} == {tuple(plan.goals[r])}}
        todo = {r: tuple(plan.goals[r]) for r in plan.ids if r not in self.confirmed}
        self._arrivals = arrival_ticks(plan.paths, plan.start_tick)   # of the plan flown: robot -> its last move's tick
        self._stops = stops(self._poses, todo, self._arrivals,
                            self.info.cell_size_m) if todo else []
        self._stop = None

    def _look_between(self, k: int) -> None:
        """Between tick k and the next: the image due now, if any (an arrival stop reached once its
        robots have made their last moves; monitoring while the vehicle holds still), and where
        the vehicle flies next. Nothing is shot from a moving vehicle, and the vehicle flies on
        as soon as the shutter has opened."""
        from .arrival_tour import next_stop

        stop = self._stop
        if stop is not None and not self._still_at(stop.pose):
            return
        if stop is not None and self._hop is not None:   # arrived: plan with the speed hops really make
            began, metres = self._hop
            self._hop = None
            self._flown_m += metres
            self._flown_s += time.perf_counter() - began
            self._fly_m_s = max(1.0, self._flown_m / self._flown_s)
        if stop is not None and k >= stop.ready_tick and len(self._glances) < MAX_GLANCES:
            self._monitor(k, stop)
            self._stops.remove(stop)
            stop = self._stop = None
        elif not self._glances and self._monitor_due(k):
            self._monitor(k)
        if stop is None and self._stops:
            ran = time.perf_counter() - self._exec_t0
            tick_s = ran / (k - self._exec_k0) if k - self._exec_k0 >= 10 else 0.05
            here = self.flight.position_ned()
            stop = self._stop = next_stop(self._stops, (here[0], here[1]), k, tick_s, self._fly_m_s)
            self.flight.go(*stop.pose)
            self._hop = (time.perf_counter(), math.dist((here[0], here[1]), stop.pose[:2]))

    def _still_at(self, pose) -> bool:
        """Settled at `pose` and level, by an attitude sample sent after the arrival was seen (see
        `_level_since`)."""
        if not self.flight.settled_at(*pose):
            self._arrived_at = None
            return False
        if self._arrived_at is None:
            self._arrived_at = self.flight.attitude_sample()[3]
        return self._level_since(self._arrived_at)

    def _last_looks(self) -> None:
        """The images that end execution: those still being perceived, then the arrival stop the
        vehicle holds at. A deviation they show, the verification's look sees too."""
        self._monitor_seen(wait=True)
        stop = self._stop
        if stop is not None and self.tick >= stop.ready_tick and self._still_at(stop.pose):
            self._monitor(self.tick, stop)
            self._stops.remove(stop)
            self._stop = None
            self._monitor_seen(wait=True)

    def _monitor_due(self, k: int) -> bool:
        every = self.cfg.monitor_every
        if every is not None:
            return every > 0 and k % every == 0
        # Auto: the images' work (render, send, perceive: off the tick loop, but on the same cores)
        # may take at most MONITOR_SHARE of the execution time. An image costs what the last one
        # did, so the next is due once the time since execution began is that large.
        if k < MONITOR_FIRST:
            return False
        spent = self._monitor_work
        last = spent / self.monitored if self.monitored else 0.0
        running = time.perf_counter() - self._exec_t0
        return (spent + last) <= MONITOR_SHARE * running

    def _monitor(self, k: int, stop=None) -> None:
        """Take one image from where the UAV holds (at `stop`, if one) while the fleet holds after
        tick k, and go on: the fleet holds only until the shutter has opened; the image is
        perceived meanwhile, and `_monitor_seen` reports the robots it shows off their planned cell
        at tick k and confirms those it shows on their goals after their last move. Robots outside
        the image are not checked until the next full look."""
        t = time.perf_counter()
        plan, fusion = self.plan, self._fusion(set(self.plan.ids))
        arrived = {r for r, tick in self._arrivals.items() if tick <= k}
        glance = _Glance(plan.plan_id, k)

        def judge(frame: CameraFrame) -> None:   # on the images' thread
            fusion.add(frame)
            model = fusion.model()
            glance.on_goal = [r for r, c in model.robots.items() if r in arrived and tuple(c) == tuple(plan.goals[r])]
            glance.took = time.perf_counter() - t
            glance.on_plan = [r for r, c in model.robots.items() if r in plan.paths and tuple(c) == plan.cell(r, k)]
            glance.off = sorted(r for r, c in model.robots.items() if r in plan.paths and tuple(c) != plan.cell(r, k))

        region = None
        if stop is not None:
            region = self._region(stop.pose, [tuple(plan.goals[r]) for r in sorted(stop.robots) if r in plan.goals])
        glance.shots = self._shots(fusion, whole=judge, roi=region)
        self._glances.append(glance)
        glance.shots.shoot(None if stop is None else stop.pose)
        self.clock.timings["monitor"] = round(self.clock.timings.get("monitor", 0.0) + time.perf_counter() - t, 4)
        self.monitored += 1

    def _region(self, pose, cells: list[Cell]):
        """The sensor region an arrival stop's image from `pose` needs to show `cells` (its robots'
        goals): those cells and the landmarks around them (`region.py`); None for the whole image
        (no cells, or a region nearly as large). The verification's look after
        the last tick takes whole images: what a region missed, it sees."""
        from .region import region_for

        if not cells:
            return None
        c = self.info.cell_size_m
        ppc = min(self._camera.fx, self._camera.fy) * c / max(pose[2], 1e-6)
        return region_for(cells, self._camera, pose, c, self.landmarks, max(self._border(self._camera, ppc, c)),
                          (self.info.width, self.info.height))

    def _monitor_seen(self, wait: bool = False) -> list[int]:
        """The robots the monitoring images perceived since the last call (all of them, if `wait`)
        show off the plan they were judged against, if it is still the one flown; the arrivals
        they show are confirmed, and the stops left with nothing to confirm dropped."""
        off: set[int] = set()
        while self._glances and (wait or self._glances[0].shots.done()):
            g = self._glances.pop(0)
            try:
                g.shots.drain()
            finally:
                g.shots.close()
            if g.off is None:   # the image missed its pose: no judgement
                continue
            self._monitor_work += g.took
            if g.plan_id != self.plan.plan_id:
                continue
            self.confirmed.update((r, g.plan_id) for r in g.on_goal)
            if self.strikes:
                self._forgive(g.on_plan)
            if g.off:
                self._event("camera-deviation", g.off, f"seen off its planned cell after tick {g.tick}")
                off.update(g.off)
        pid = self.plan.plan_id
        self._stops = [s for s in self._stops if not all(self.confirmed.get(r) == pid for r in s.robots)]
        if self._stop not in self._stops:
            self._stop = None
        return sorted(off)

    def _done_for(self, robot: int, plan: PlanState) -> bool:
        d = self.fleet.done.get(robot)
        return d is not None and d.tick > plan.start_tick

    def _off_goal(self) -> list[int]:
        """Working robots the last look did not find on their goals (a skid, a late slip): replanned."""
        with self.fleet.cv:
            alive = set(self.fleet.alive)
        return sorted(r for r in self.plan.ids if not self.verified.get(r) and r in alive and r not in self.blocked)

    def _drop_the_gone(self) -> None:
        """Robots of the plan whose session went away after its last tick, and that no image shows on
        their goal: lost, out of the plan (nothing to repair: they cannot move)."""
        with self.fleet.cv:
            gone = sorted(r for r in self.plan.ids if r not in self.fleet.alive and not self.verified.get(r)
                          and r not in self.blocked)
        if not gone:
            return
        self._event("robot-lost", gone, "liveliness gone after the last tick, not seen on its goal",
                    "out of the plan")
        for r in gone:
            self.blocked[r] = tuple(self.fleet.cells.get(r) or self.plan.cell(r, self.tick))
            self.blocked_at[r] = time.monotonic()
            self.out_reason[r] = "lost: liveliness gone"

    def _rejoining(self) -> list[int]:
        """Robots taken out of the plan that are back: alive, heard of since, no error, not quarantined."""
        with self.fleet.cv:
            return sorted(r for r in self.blocked if r in self.fleet.alive and r not in self.fleet.errors
                          and r not in self.quarantined
                          and self.fleet.heard.get(r, 0.0) > self.blocked_at.get(r, 0.0))

    def _recover(self, k: int, faults: dict[str, list[int]]) -> None:
        """Hold the fleet at tick k, look, take the robots that cannot move out of the plan, replan the rest.
        A robot that keeps failing is quarantined; robots the camera verified on their goals stay there."""
        from .planning.registry import DEFAULT_PLANNER
        from .recovery import replan

        t = time.perf_counter()
        self.replans += 1
        faulty = set(faults.get("lost", [])) | set(faults.get("error", [])) | set(faults.get("stalled", []))
        for kind, robots in faults.items():
            if not robots:
                continue
            what = {"lost": "liveliness gone", "error": "reported status error",
                    "stalled": f"no state for tick {k} within {self.cfg.tick_timeout_s:g} s",
                    "deviation": "reported a cell off its plan", "rejoin": "back and reporting"}[kind]
            self._event(f"robot-{kind}", robots, what, f"fleet held at tick {k}; fresh look; replan")
        self._status("recover", message=f"tick {k}: {', '.join(f'{a} {b}' for a, b in faults.items())}")
        # Hold at the tick boundary: the robots still working finish tick k before the look, so the
        # image shows a settled floor (a lost robot is noticed while the others are mid-tick).
        settling = [r for r in self.plan.ids if r not in faulty]
        self.fleet.wait_tick(settling, k, self.cfg.tick_timeout_s, interrupt=self._interrupted)
        self._check_vehicle()
        seen = self._look()
        with self.fleet.cv:
            alive = set(self.fleet.alive)
            reported = dict(self.fleet.cells)
            self.fleet.errors.clear()
        for r in faults.get("rejoin", []):
            self.blocked.pop(r, None)
            self.blocked_at.pop(r, None)
            self.out_reason.pop(r, None)
        kind_of = {r: kind for kind, robots in faults.items() if kind != "rejoin" for r in robots}
        working: dict[int, Cell] = {}
        for r in self.ids:
            cell = seen.get(r) or reported.get(r) or self.blocked.get(r)
            if r in faulty or r in self.blocked or r not in alive or r not in seen:
                if cell is not None:
                    self.blocked[r] = tuple(cell)
                    if r not in self.blocked_at or r in faulty:
                        self.blocked_at[r] = time.monotonic()
                if r not in self.quarantined:
                    self.out_reason[r] = ("lost: liveliness gone" if r not in alive else
                                          kind_of.get(r) or self.out_reason.get(r) or "not seen by the fresh look")
            else:
                working[r] = seen[r]
        also = sorted(r for r in working if r in self.plan.paths and r not in kind_of
                      and working[r] != self.plan.cell(r, k))
        if also:
            self._event("camera-deviation", also, f"the fresh look found them off their plan after tick {k}",
                        "replanned from where they are")
        unseen = [r for r in self.ids if r not in seen]
        if unseen:
            self._event("unseen", unseen, "not seen by the fresh look", "kept out of the plan")
        # Unseen robots count too: one the camera keeps missing would otherwise rejoin and be left out
        # again at every tick.
        culprits = {**{r: "unseen" for r in unseen if r in self.plan.paths}, **kind_of,
                    **{r: "deviation" for r in also}}
        # Seen on its plan's cell, or back and seen: a fresh start (a robot that stalled once and came
        # back is not one slip away from quarantine).
        self._forgive([r for r in self.strikes if r in working and r not in culprits and
                       (r in faults.get("rejoin", []) or r in self.plan.paths and working[r] == self.plan.cell(r, k))])
        for r in self._strike(k, culprits):
            if r in working:
                self.blocked[r] = working.pop(r)
                self.blocked_at[r] = time.monotonic()
        lost = sorted(set(self.ids) - alive)
        t_look = time.perf_counter() - t
        t = time.perf_counter()
        pid = self.plan.plan_id
        pinned = {r: self.goal_of[r] for r in working
                  if self.confirmed.get(r) == pid and working[r] == tuple(self.goal_of.get(r, ()))}
        try:
            rep = replan(self.model_free, list(self.model.goals), working, self.blocked,
                         planner=self.cfg.planner or DEFAULT_PLANNER, connectivity=self.cfg.connectivity,
                         time_limit=self.cfg.time_limit_s, seed=self.cfg.seed, plan=self._plan_mission,
                         pinned=pinned)
        except PlanningError as exc:
            # The mission's input was fine; what happened to its fleet ends it: a failed mission
            # (exit 1), not a bad input (exit 2), as the UAV alone used to say.
            raise MissionError(f"no repair after tick {k}: {exc}") from None
        for r, why in rep.stranded.items():
            self._quarantine(r, f"stranded: {why}", working.pop(r))
        # A goal under a stopped robot that had reached it is served, not lost.
        self.unserved = [tuple(g) for g in rep.unserved
                         if not any(self.goal_of.get(r) == tuple(g) and c == tuple(g) for r, c in self.blocked.items())]
        self._progress(rep, culprits)
        new = PlanState(secrets.token_hex(4), k, rep.paths, rep.goals)
        self._event("replan", rep.ids, f"plan {new.plan_id} from tick {k} for {len(rep.ids)} robots "
                                       f"({len(rep.pinned)} kept on their verified goals; {len(self.blocked)} out: "
                                       f"{sorted(self.blocked)}, lost {lost}); {len(self.unserved)} goal(s) unserved",
                    f"looked in {t_look:.2f} s, replanned in {time.perf_counter() - t:.3f} s")
        self.clock.timings["recover_look"] = round(self.clock.timings.get("recover_look", 0.0) + t_look, 4)
        failed = self._dispatch(new)
        if failed:
            self._recover(k, {"error": failed})

    def _strike(self, k: int, culprits: dict[int, str]) -> list[int]:
        """Count each robot's fault; returns the robots quarantined now: MAX_STRIKES faults without a
        planned move between, or named by MAX_FRUITLESS repairs in a row that got the fleet no nearer."""
        out = []
        for r, kind in culprits.items():
            self._clean_moves.pop(r, None)
            self.strikes.setdefault(r, []).append(f"{kind}@{k}")
            if len(self.strikes[r]) >= MAX_STRIKES and r not in self.quarantined:
                out.append(r)
                self._quarantine(r, f"{len(self.strikes[r])} faults in a row, never shown on its plan between "
                                    "(an image, or two moves kept in a row): " + ", ".join(self.strikes[r]))
        if self._fruitless >= MAX_FRUITLESS:
            named = sorted((self._fruitless_culprits | set(culprits)) - set(self.quarantined))
            for r in named:
                out.append(r)
                self._quarantine(r, f"named by {self._fruitless} repairs in a row that brought the fleet "
                                    "no nearer its goals")
            self._fruitless, self._fruitless_culprits = 0, set()
        return out

    def _quarantine(self, robot: int, why: str, cell: Cell | None = None) -> None:
        """Out of the plan for good: its cell an obstacle, its goal given to another, never rejoined."""
        self.quarantined[robot] = why
        self.out_reason[robot] = f"quarantined: {why}"
        if cell is not None:
            self.blocked[robot] = tuple(cell)
            self.blocked_at[robot] = time.monotonic()
        self._event("robot-quarantined", [robot], why, "out of the plan for good; the others go on")

    def _progress(self, rep, culprits: dict[int, str]) -> None:
        """Whether this repair got the fleet nearer its goals than any before it with the same working
        robots (a lower bound below the best); repairs that do are not failures."""
        working = frozenset(rep.ids)
        best = self._best_lb
        if best is None or best[0] != working or rep.lower_bound < best[1]:
            self._best_lb = (working, rep.lower_bound)
            self._fruitless, self._fruitless_culprits = 0, set()
        else:
            self._fruitless += 1
            self._fruitless_culprits |= set(culprits)

    def _verify(self) -> None:
        """Believe a Done only when an image taken after it shows the robot on its goal."""
        plan = self.plan
        deadline = time.monotonic() + DONE_WAIT_S
        with self.fleet.cv:
            while not all(self._done_for(r, plan) for r in plan.ids) and time.monotonic() < deadline:
                self._check_vehicle()
                self.fleet.cv.wait(0.1)
            claimed = {r for r in self.ids if r in self.fleet.done}
        self._status("verify", message=f"a fresh look at {len(plan.ids)} robots' goals")
        goals = {r: self.goal_of.get(r) for r in self.ids}
        # Only the goals matter: a robot anywhere else is not on its goal, seen or not. Arrivals
        # an image confirmed during execution need no second look.
        # The vehicle lands where the look ends, unless a repair follows (then it flies back anyway).
        confirmed = {r for r in plan.ids if self.confirmed.get(r) == plan.plan_id}
        cells = [tuple(g) for r, g in goals.items() if g is not None and r not in confirmed]
        self.progress.phase("verify", f"{len(confirmed)} arrival(s) seen during execution; a look at "
                                      f"{len(cells)} more goal(s)")
        looked_for = {r for r, g in goals.items() if g is not None and r not in confirmed}
        seen = self._look(cells, back=False, expected=looked_for) if cells else {}
        nowhere = {r: tuple(goals[r]) for r in claimed if goals.get(r) is not None and r not in seen
                   and r not in confirmed}
        if nowhere:
            seen.update(self._closer_at_goals(nowhere))
        seen.update((r, tuple(goals[r])) for r in confirmed)
        self.seen_at_end = seen
        for r in self.ids:
            g = goals[r]
            self.verified[r] = g is not None and seen.get(r) == tuple(g)
            if r in claimed and not self.verified[r] and r not in self._contradicted:
                self._contradicted.add(r)
                where = f"on {seen[r]}" if r in seen else "nowhere"
                self._event("done-contradicted", [r], f"raised Done but the camera sees it {where}"
                                                      + (f", not on its goal {tuple(g)}" if g else ""),
                            "counted as not arrived")
            elif r in plan.ids and r not in claimed and self.verified[r]:
                self._event("done-missing", [r], "on its goal but raised no Done", "counted as arrived (seen)")
        self.clock.lap("verify")

    def _closer_at_goals(self, goals: dict[int, Cell]) -> dict[int, Cell]:
        """Robots that raised Done but that the verification's look saw nowhere: their goals once
        more from half the height, as the survey looks closer at what it could not read (a robot
        parked on its goal shows its marker inside the pad's green frame, which a blurred camera
        reads less often than one on bare floor). The robots that look sees, where it sees them."""
        from .perception.relook import detail_hovers

        here = self.flight.position_ned()
        hovers = detail_hovers(sorted(set(goals.values())), 1, self._survey_alt, self.info.cell_size_m, self._camera,
                               self.landmarks, (here[0], here[1]), math.radians(LEVEL_TILT_DEG), len(self._poses))
        self._event("closer-look", sorted(goals), "raised Done, seen nowhere by the verification's look",
                    f"{len(hovers)} hover(s) at {sorted({round(a, 1) for _, _, a in hovers})} m over their goals")
        fusion = self._fusion(set(self.ids))   # the whole codebook: a neighbour's marker is not taken for theirs
        self._tour(hovers, fusion)
        return {r: tuple(c) for r, c in fusion.model().robots.items() if r in goals}

    def _outcome(self) -> str:
        """completed: every robot seen on a goal; degraded: every working robot is, some were lost; else failed."""
        if self.verified and all(self.verified.values()):
            return "completed"
        working = [r for r in self.ids if r not in self.blocked]
        if working and all(self.verified.get(r) for r in working):
            return "degraded"
        return "failed"

    def _reason(self) -> str:
        outcome = self._outcome()
        n, ok = len(self.ids), sum(self.verified.values())
        if outcome == "completed":
            return f"all {n} robots verified on their goals"
        out = "; ".join(f"{r} {self.out_reason.get(r, '')}".rstrip() for r in sorted(self.blocked)[:10])
        out += f"; ... {len(self.blocked) - 10} more" if len(self.blocked) > 10 else ""
        return f"{ok}/{n} robots verified on their goals; out of the plan: {out or 'none'}"

    def _end(self, completed: bool, reason: str) -> None:
        if self._ended:
            return
        self._ended = True
        if getattr(self, "previewer", None) is not None:
            self.previewer.close()   # the mission's last images reach observers before its end
        self.transport.put(self.keys.mission_end, encode(MissionEnd(completed=completed, reason=reason,
                                                                    seq=self._next())))

    def _stopped(self, exc: BaseException) -> None:
        """Stopped from outside: the report first (a second signal must not lose it), then a bounded
        landing, then the report again with the landing's outcome. Further signals wait meanwhile:
        the stop is bounded by STOP_LAND_TIMEOUT_S and the record's query."""
        why = "stopped by SIGTERM" if isinstance(exc, SystemExit) else "interrupted (SIGINT)"
        held = _hold_signals()
        try:
            self._event("abort", [], why, "ended the mission, wrote the report; " + self._abort_course())
            try:
                self._end(False, why)
            except Exception:  # noqa: BLE001 - the session may already be gone
                pass
            self._abort_report(why, record_timeout_s=2.0)
            if self.flight is not None and self.uav["armed"] and not self.uav["landed"]:
                self._abort_landing(STOP_LAND_TIMEOUT_S)
                self._abort_report(why, record_timeout_s=2.0)
        finally:
            _restore_signals(held)

    def _abort_course(self) -> str:
        """What becomes of the vehicle after an abort, as `_abort_landing` will do it."""
        if self.flight is None or not self.uav["armed"] or self.uav["landed"]:
            return "the vehicle stays on the ground"
        if self.watch is not None and self.watch.failsafe:
            return "the autopilot brings the vehicle down"
        return "landing the vehicle"

    def _abort_landing(self, timeout_s: float = ABORT_LAND_TIMEOUT_S) -> None:
        if self.watch is not None:
            self.watch.expect_airborne(False)
        if self.flight is None or not self.uav["armed"] or self.uav["landed"]:
            return
        try:
            self._end(False, "mission aborted")
            if self.watch is not None and self.watch.failsafe:
                self._follow_down(timeout_s)
                return
            spot = self._abort_spot()
            if spot is not None:
                self.progress.phase("abort", f"flying off the floor to land at N {spot[0]:.1f} E {spot[1]:.1f}")
                try:
                    self.flight.goto(*spot, timeout_s=timeout_s / 2)
                except MissionError as exc:   # land where it is rather than not at all
                    self.progress.phase("abort", f"could not reach the landing spot: {exc}")
            self.progress.phase("abort", "landing the vehicle")
            self.flight.land(timeout_s=timeout_s)
            if self.pose_feed is not None:
                self.pose_feed.flying(False)
            self.uav["landed"] = True
        except Exception as exc:  # noqa: BLE001 - the link may be the thing that failed
            self.progress.phase("abort", f"could not land: {exc}")

    def _follow_down(self, timeout_s: float) -> None:
        """The autopilot took the vehicle (a failsafe's RTL or LAND, a pilot, a disarm): no command of the
        mission's goes over its decision, not even a landing; the mission only watches it come down."""
        taken = self.watch.taken_by
        self.uav["left_to_autopilot"] = taken
        self.progress.phase("abort", f"the autopilot has the vehicle ({taken}): not commanding it, watching it land")
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                if self.flight.landed:
                    self.uav["landed"] = True
                    break
            except MissionError:
                break
            time.sleep(0.2)
        if self.pose_feed is not None and self.uav["landed"]:
            self.pose_feed.flying(False)

    def _abort_spot(self) -> tuple[float, float, float] | None:
        """Where an abort lands (`landing.abort_spot`); None before the floor is known or on the ground."""
        from .landing import abort_spot

        info = getattr(self, "info", None)
        if info is None or not self.flight.in_air:
            return None
        n, e, d = self.flight.position_ned()
        return abort_spot(n, e, -d, info.width, info.height, info.cell_size_m)

    def _land(self) -> None:
        self._status("land", message="landing over MAVLink")
        self.flight.land()
        self.pose_feed.flying(False)
        self.uav["landed"] = True
        self.clock.lap("land")

    def _record(self, timeout_s: float = QUERY_TIMEOUT_S) -> Record | None:
        if hasattr(self, "fleet") and self.fleet.world_gone:
            return None
        try:
            return _query(self.transport, self.keys.record, RecordRequest(seq=self._next()), Record, "record",
                          timeout_s)
        except MissionError:
            return None

    def _cross_check(self, record: Record) -> None:
        """The world's record against what the UAV believes: any disagreement is reported."""
        hits = [f for f in record.refused if f.get("collision")]
        if hits:
            self._event("collision", sorted({f["robot"] for f in hits}), f"the world refused {len(hits)} illegal "
                        f"move(s), first at tick {hits[0]['tick']}: {hits[0]['reason']}")
        vehicle = (record.truth or {}).get("vehicle")
        if vehicle:
            if self.uav["landed"] and (vehicle.get("armed") or vehicle.get("landed_state") != "ON_GROUND"):
                self._event("record-mismatch", [], f"the UAV believes it landed; the vehicle says armed "
                                                   f"{vehicle.get('armed')}, {vehicle.get('landed_state')}")
            crashes = [text for _, text in vehicle.get("events", []) if "hit the ground" in text]
            if crashes:
                # A touchdown that hard is a crash, not a landing, whatever the UAV believed.
                self.uav["landed"], self.uav["crashed"] = False, True
                self._event("vehicle", [], f"the vehicle's own record: {crashes[0]}")
        seen = getattr(self, "seen_at_end", {})
        for rid, cells in record.executed.items():
            r = int(rid)
            if cells and r in seen and tuple(cells[-1]) != tuple(seen[r]):
                self._event("record-mismatch", [r], f"the world's record ends on {tuple(cells[-1])}, "
                                                    f"the camera saw {tuple(seen[r])}")

    def _fill_report(self, record: Record | None, outcome: str, reason: str) -> None:
        from protocol.mapfile import format_rows

        from .planning.plan_io import plan_to_dict

        ids = getattr(self, "ids", [])
        model, result = self.model, self.first_result
        self.report.update({
            "completed": outcome == "completed" and record is not None and record.collisions == 0,
            "outcome": outcome,
            "reason": reason,
            "robots": len(ids),
            "done": sorted(r for r in self.fleet.done if r in ids) if hasattr(self, "fleet") else [],
            "foreign_messages": self.fleet.foreign if hasattr(self, "fleet") else 0,
            "verified": {str(r): self.verified.get(r, False) for r in ids},
            "verified_during_execution": sorted(r for r, pid in self.confirmed.items()
                                                if self.plan is not None and pid == self.plan.plan_id),
            "lost": sorted(self.blocked),
            "out_of_plan": {str(r): self.out_reason.get(r, "") for r in sorted(self.blocked)},
            "quarantined": sorted(self.quarantined),
            "unserved_goals": [list(g) for g in self.unserved],
            "replans": self.replans,
            "monitor_images": self.monitored,
            "events": self.events.as_dicts(),
            "collisions": record.collisions if record else None,
            "safety_stops": (record.truth or {}).get("safety_stops", 0) if record else None,
            "refused": record.refused if record else [],
            "ticks": self.tick,
            "plan": plan_to_dict(result, model.free, ids=ids) if result is not None else None,
            "executed": record.executed if record else {},
            "perceived": None if model is None else {
                "rows": format_rows(model.free), "robots": {str(i): list(c) for i, c in sorted(model.robots.items())},
                "goals": [list(g) for g in model.goals], "images": len(self.frames),
                "unsure": [list(c) for c in model.unsure],
                "registration": _registration_summary(getattr(self, "perception_frames", [])),
                "warnings": getattr(self, "perception_warnings", [])},
            "truth": record.truth if record else None,
            "uav": self.uav,
            "timings": self.clock.timings,
            "processes": {"uav": os.getpid()},
            "fleet": self.cfg.fleet,
        })

    def _finish_report(self) -> None:
        record = self._record()
        if record is not None:
            self._cross_check(record)
        outcome = self._outcome()
        if record is not None and record.collisions:
            outcome = "failed"
        self._fill_report(record, outcome, self._reason())
        self.clock.lap("report")
        self.report["timings"] = self.clock.timings
        if self.cfg.out is not None:
            write_outputs(self.cfg.out, self.report, self.frames, self.model.free, self.first_result, self.ids)

    def _abort_report(self, reason: str, record_timeout_s: float = QUERY_TIMEOUT_S) -> None:
        """An aborted mission still leaves its report: completed false, the reason, the events, and the
        robots an image showed on their goals after their last move (verified, whatever came after)."""
        try:
            if self.plan is not None and not self.verified:
                self.verified = {r: self.confirmed.get(r) == self.plan.plan_id for r in getattr(self, "ids", [])}
            record = self._record(record_timeout_s)
            if record is not None:
                self._cross_check(record)
            self._fill_report(record, "aborted", reason)
            if self.cfg.out is not None:
                write_report(self.cfg.out, self.report)
        except Exception as exc:  # noqa: BLE001 - the report must not hide the abort's own error
            self.progress.phase("abort", f"could not write the report: {exc}")


def _check_floor(info: WorldInfo) -> None:
    """A floor larger than one survey covers ends the mission before the vehicle flies."""
    from protocol.errors import UavRobotsError
    from scenarios.limits import check_floor

    try:
        check_floor(info.width, info.height, "the world's floor")
    except UavRobotsError as exc:
        raise MissionError(str(exc)) from None


def _hold_signals() -> list:
    """SIGTERM and SIGINT ignored for a while (only the main thread may say so; elsewhere nothing)."""
    import signal

    held = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        try:
            held.append((sig, signal.signal(sig, signal.SIG_IGN)))
        except ValueError:
            pass
    return held


def _restore_signals(held: list) -> None:
    import signal

    for sig, handler in held:
        signal.signal(sig, handler)


def _registration_summary(frames) -> dict[str, Any]:
    """How the survey's images were placed on the floor: by landmarks or by the pose estimate alone."""
    errors = [f.reprojection_px for f in frames if f.source == "landmarks" and f.reprojection_px is not None]
    return {"by_landmarks": sum(f.source == "landmarks" for f in frames),
            "by_estimate": sum(f.source != "landmarks" for f in frames),
            "reprojection_px_max": round(max(errors), 3) if errors else None,
            "reprojection_px_median": round(sorted(errors)[len(errors) // 2], 3) if errors else None}


def exit_code(report: dict[str, Any]) -> int:
    """0 every robot verified on its goal; 3 finished with a degraded fleet; 1 failed or aborted."""
    if report.get("completed"):
        return EXIT_COMPLETED
    return EXIT_DEGRADED if report.get("outcome") == "degraded" else EXIT_ABORTED


DETAILS = "details.json"   # the per-tick and per-cell data, beside the compact report.json
PLAN = "plan.json"         # the first plan, in the plan file format (uav-robots plan --out)
GIF_MAX_SIDE = 64          # cells: beyond, a robot is a pixel or two in a GIF


def split_report(report: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any] | None]:
    """(report.json, details.json, plan.json): what a person reads apart from the bulk a program reads."""
    compact = {k: v for k, v in report.items() if k not in ("executed", "refused")}
    plan = report.get("plan")
    if plan is not None:
        compact["plan"] = {**{k: v for k, v in plan.items() if k not in ("map", "robots")}, "file": PLAN,
                           "robots": [{"id": r["id"], "start": r["start"], "goal": r["goal"]} for r in plan["robots"]]}
    rows = {}
    for part in ("perceived", "truth"):
        if report.get(part):
            compact[part] = {k: v for k, v in report[part].items() if k != "rows"}
            rows[part] = report[part].get("rows")
    if rows.get("perceived") is not None and rows.get("truth") is not None:
        compact["perceived"]["map_matches_truth"] = rows["perceived"] == rows["truth"]
    details = {"format": "uav-robots-details/1", "executed": report.get("executed", {}),
               "refused": report.get("refused", []), "rows": rows}
    compact["details"] = DETAILS
    return compact, details, plan


def _write_whole(path: Path, data: str | bytes) -> None:
    """The file whole or not at all (a full disk must not leave half a report standing): written beside,
    then renamed over (`.partial-*` left behind by a kill is removed by the launcher)."""
    tmp = path.with_name(f".partial-{path.name}")
    try:
        (tmp.write_bytes if isinstance(data, bytes) else tmp.write_text)(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_report(out: Path, report: dict[str, Any]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    compact, details, plan = split_report(report)
    _write_whole(out / "report.json", json.dumps(compact, indent=1))
    _write_whole(out / DETAILS, json.dumps(details, separators=(",", ":")))
    if plan is not None:
        _write_whole(out / PLAN, json.dumps(plan, separators=(",", ":")))


def load_report(out: Path) -> dict[str, Any]:
    """report.json with details.json and plan.json put back in: the whole record of a mission."""
    report = json.loads((out / "report.json").read_text())
    details = json.loads((out / DETAILS).read_text()) if (out / DETAILS).exists() else {}
    report["executed"] = details.get("executed", {})
    report["refused"] = details.get("refused", [])
    for part, rows in details.get("rows", {}).items():
        if report.get(part) is not None:
            report[part]["rows"] = rows
    if (out / PLAN).exists():
        report["plan"] = json.loads((out / PLAN).read_text())
    return report


def write_outputs(out: Path, report: dict[str, Any], frames: list[CameraFrame], free, result,
                  ids: list[int]) -> None:
    """report.json (+ details.json, plan.json), overhead.png (a captured image), paths.png and replay.gif."""
    from . import visualize

    write_report(out, report)   # first: the pictures are worth less than the record
    executed = {int(k): [tuple(c) for c in v] for k, v in report["executed"].items()}
    goals = {rid: tuple(g) for rid, g in zip(ids, result.goals)}
    pictures = [("overhead.png", lambda: _write_whole(out / "overhead.png", frames[len(frames) // 2].png)
                 if frames else None),
                ("paths.png", lambda: visualize.write_png(out / "paths.png",
                                                          visualize.draw_paths(free, result.paths, result.goals))),
                # larger floors: replay.mp4 (uav-robots run --out) is readable
                ("replay.gif", lambda: visualize.replay_gif(out / "replay.gif", free, executed, goals)
                 if max(free.shape) <= GIF_MAX_SIDE else None)]
    for name, write in pictures:
        try:
            write()
        except OSError as exc:
            print(f"uav: could not write {out / name}: {exc.strerror or exc}", file=sys.stderr, flush=True)


def summary(report: dict[str, Any], out: Path | None) -> str:
    """The few lines a person reads at the end of a mission."""
    t = report["timings"]
    verified = report.get("verified", {})
    outcome = report.get("outcome", "completed" if report["completed"] else "failed").upper()
    lines = [
        f"mission {outcome}: {sum(verified.values())}/{report['robots']} robots verified on their goals by the "
        f"camera in {report['ticks']} ticks, collisions {report['collisions']}"
        + (f" (safety stops {report['safety_stops']}: robots stopped by one that failed or slipped unseen)"
           if report.get("safety_stops") else ""),
    ]
    if report.get("plan"):
        m = report["plan"]["metrics"]
        lines.append(f"  plan: {report['plan'].get('planner', '?')}, sum of costs {m['sum_of_costs']} "
                     f"(lower bound {m.get('lower_bound', '?')}), makespan {m['makespan']}")
    events = report.get("events", [])
    if events or report.get("replans"):
        lines.append(f"  events: {len(events)}, replans {report.get('replans', 0)}, out of the plan "
                     f"{report.get('lost', [])}, unserved goals {report.get('unserved_goals', [])}")
        for e in events[:8]:
            lines.append(f"    tick {e['tick']}: {e['kind']} {e['robots']} {e['what']}"
                         + (f" -> {e['action']}" if e["action"] else ""))
        if len(events) > 8:
            lines.append(f"    ... {len(events) - 8} more in report.json")
    if report.get("outcome") not in (None, "completed"):
        lines.append(f"  reason: {report.get('reason', '')}")
    lines += [
        f"  uav: armed {report['uav']['armed']}, max altitude {report['uav']['max_altitude_m']} m, "
        f"landed {report['uav']['landed']}",
        "  time: " + ", ".join(f"{k} {v:.2f}s" for k, v in t.items()),
    ]
    if out:
        gif = ", replay.gif" if (out / "replay.gif").exists() else ""
        lines.append(f"  outputs: {out}/report.json, details.json, plan.json, overhead.png, paths.png{gif}")
    return "\n".join(lines)
