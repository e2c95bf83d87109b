"""The one context every phase of a mission works on: the session and its keys, what is said
(status, events), the vehicle's check, and the mission's state (`state.py`), every field set here."""
from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

from protocol.errors import MissionError
from protocol.keys import Keys
from protocol.messages import CameraFrame, MissionEvent, MissionStatus, WorldInfo
from protocol.codec import encode
from protocol.transport import Transport, open_session, zenoh_config

from ..camera_source.base import CameraSource
from ..camera_source.fresh import OUTAGE_S, RETRY_S, Freshness, usable
from ..events import EventLog
from ..fleet import FleetLink
from ..preview import Previewer
from ..progress import Progress
from .config import MissionConfig
from .state import Arrivals, Clock, Compile, Plans, Roster, Vantage

if TYPE_CHECKING:
    from ..flight import Flight
    from ..pose_feed import PoseFeed
    from ..shots import Shots
    from ..watch import VehicleWatch

CAMERA_TIMEOUT_S = 30.0    # a 12 MP image rendered on a loaded machine, or sent over a slow link
PERCEPTION_WORKERS = 2     # survey images measured at once (OpenCV releases the GIL): a second core's worth
# An image whose own published attitude leans further is taken again: beyond the level the shutter
# accepts by four sigmas of a realistic attitude estimate (0.2 degrees), and about the most the
# survey's border absorbs (LEVEL_TILT_DEG's swing plus the hold tolerance's pixels).
RETAKE_TILT_DEG = 1.5


def open_transport(cfg: MissionConfig) -> Transport:
    # Alone, the UAV joins a router already on this machine (a world started first) or becomes it.
    return open_session("uav", cfg.listen, cfg.connect, cfg.zenoh_config, alone="either")


def access_control(cfg: MissionConfig) -> bool:
    """Whether this UAV's router applies access control (`uav-robots run --secure`): a robot of protocol 1
    then cannot move, since it asks on the plain P/world/move (docs/protocol.md, Versioning)."""
    if not cfg.zenoh_config:
        return False
    from protocol.config import config_from_file
    return bool(json.loads(zenoh_config(config_from_file(cfg.zenoh_config)).get_json("access_control/enabled")
                           or "false"))


class MissionContext:
    """Built on an open session: the UAV announces itself and listens to the fleet from here on.
    The vehicle, the floor and the camera come with the `start` phase (None until then)."""

    def __init__(self, cfg: MissionConfig, transport: Transport, progress: Progress | None = None) -> None:
        self.cfg = cfg
        self.keys = Keys(cfg.fleet)
        self.transport = transport
        self.progress = progress or Progress()
        self.clock = Clock()
        self.seq = 0
        self.report: dict[str, Any] = {"format": "uav-robots-report/1", "completed": False}
        self.uav: dict[str, Any] = {"mavlink_url": cfg.mavlink_url, "armed": False,
                                    "max_altitude_m": 0.0, "hover": None, "landed": False}
        self.frames: list[CameraFrame] = []
        self.events = EventLog()
        self.secured = access_control(cfg)   # a robot of protocol 1 cannot move: refused
        self.older_said: set[int] = set()     # robots of an older protocol, said once each
        self.tick = 0                         # the last tick sent
        self.ended = False                    # MissionEnd is out
        self.plans = Plans()
        self.movers = None                    # movers.MoverWatch, once people, forklifts or pallets are watched
        self.roster = Roster()
        self.arrivals = Arrivals()
        self.vantage = Vantage()
        self.compile = Compile()
        self.perception_warnings: list[str] = []
        self.perception_frames: list = []     # how the survey's images were registered
        self.info: WorldInfo | None = None
        self.landmarks = None                 # perception.Landmarks of the floor, if it has any
        self.flight: Flight | None = None
        self.watch: VehicleWatch | None = None
        self.pose_feed: PoseFeed | None = None
        self.camera: CameraSource | None = None   # camera_source: the world's query, MAVLink's camera or a video stream
        self.freshness = Freshness()              # the images' stamps: a frozen camera's old image is refused
        self.token = transport.announce(self.keys.alive_uav)
        self.previewer = Previewer(lambda f: self.transport.put(self.keys.uav_frame, encode(f)))
        self.fleet = FleetLink(transport, self.keys, cfg.robots)

    def next_seq(self) -> int:
        self.seq += 1
        return self.seq

    def status(self, phase: str, **kw: Any) -> None:
        self.transport.put(self.keys.mission_status, encode(MissionStatus(phase=phase, seq=self.next_seq(), **kw)))
        if phase != "executing":
            self.progress.phase(phase, kw.get("message", ""))

    def event(self, kind: str, robots, what: str, action: str = "") -> None:
        e = self.events.add(self.tick, kind, list(robots), what, action)
        try:   # for observers; the event log (report.json) is the record
            self.transport.put(self.keys.mission_event, encode(MissionEvent(
                tick=e.tick, time_s=e.time_s, kind=kind, robots=list(e.robots), what=what, action=action,
                seq=self.next_seq())))
        except Exception:  # noqa: BLE001 - an abort's event must not be lost to a closing session
            pass
        self.progress.phase("event", f"tick {e.tick}: {kind} {list(e.robots) or ''} {what}"
                                     + (f" -> {action}" if action else ""))

    def vehicle_fault(self, why: str) -> None:
        self.event("vehicle", [], why, "the mission stops")

    def check_vehicle(self) -> None:
        if self.watch is not None and self.watch.fault:
            raise MissionError(f"vehicle: {self.watch.fault}")
        if self.fleet.world_gone:
            raise MissionError("the world went away (its alive/world token vanished): nobody judges the "
                               "robots' moves or renders the camera")

    def interrupted(self) -> bool:
        """A tick's wait ends early when the vehicle or the world fails (both end the mission)."""
        return (self.watch is not None and self.watch.fault is not None) or self.fleet.world_gone

    def track_altitude(self) -> None:
        north, east, down = self.flight.position_ned()
        self.uav["max_altitude_m"] = round(max(self.uav["max_altitude_m"], -down), 2)

    def telemetry_pose(self) -> tuple[float, float, float, float, float, float]:
        """(north, east, down, yaw, roll, pitch) from the autopilot: a video frame's pose."""
        if self.flight is None:
            raise MissionError("no autopilot yet")
        north, east, down, yaw = self.flight.pose()
        roll, pitch, _ = self.flight.attitude_rad()
        return north, east, down, yaw, roll, pitch

    def capture(self, calibration_only: bool = False) -> CameraFrame:
        """One usable image (or the calibration): a camera that gives none, or only a frozen one, is asked
        again for a while (camera_source/fresh.py), said once as a `camera-outage` event."""
        frame = usable(lambda: self.camera.frame(calibration_only), self.freshness,
                       lambda why: self.event("camera-outage", [], why,
                                              f"asking again every {RETRY_S:g} s for up to {OUTAGE_S:g} s"),
                       self.interrupted)
        if frame.png:
            self.took(frame)
        return frame

    def took(self, frame: CameraFrame) -> None:
        self.frames.append(frame)
        self.previewer.submit(frame)

    def fusion(self, known: set[int] | None = None):
        from ..perception import Fusion

        return Fusion(self.info.width, self.info.height, self.info.cell_size_m, known_ids=known,
                      landmarks=self.landmarks)

    def shots(self, fusion, measure=None, whole=None, roi=None) -> "Shots":
        """Images asked for on the move, perceived as they arrive: measured (by `measure`, else
        `fusion.measure`, frames at once) and merged into `fusion` in order, or each handed
        whole to `whole`, which perceives it itself; only the sensor's region `roi`, if given."""
        from ..shots import Shots

        return Shots(lambda: self.camera.start(roi), self.took, whole or measure or fusion.measure, CAMERA_TIMEOUT_S,
                     fence=self.camera.fence,
                     merge=None if whole else fusion.merge, workers=PERCEPTION_WORKERS,
                     max_tilt_rad=math.radians(RETAKE_TILT_DEG), stale=self.freshness.stale)

    def done_for(self, robot: int, plan) -> bool:
        d = self.fleet.done.get(robot)
        return d is not None and d.tick > plan.start_tick
