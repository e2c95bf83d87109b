"""The `Vehicle` facade: builds the parts, wires them together and runs their threads."""
from __future__ import annotations

import math
import threading
import time

from protocol.errors import MissionError

from .autopilot import Autopilot
from .battery import Battery
from .commands import Commands
from .config import VehicleConfig
from .datalink import Datalink
from .dynamics import Dynamics, State
from .estimator import Estimator
from .journal import Journal
from .link import Link
from .link_loss import LinkLoss
from .mission import Mission
from .mission_protocol import MissionService
from .modes import LandedState, Mode
from .offboard import Offboard
from .params import Params
from .payload import Payload, Trigger
from .telemetry import Telemetry


class Vehicle:
    """The simulated autopilot. `start()` opens the link and runs its threads; `stop()`
    ends them. All public accessors are thread-safe."""

    def __init__(self, config: VehicleConfig | None = None):
        self.config = cfg = config or VehicleConfig()
        # One lock for all the parts' state: a command, a physics step or a telemetry
        # message sees every part at the same instant. Re-entrant, since parts call each
        # other while holding it.
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        # Events carry simulated time, which the airframe (built next, and logging to the
        # journal) keeps.
        self._journal = Journal(self._lock, sim_time=lambda: self._dynamics.sim_time)
        self._link = Link(cfg, self._lock, self._journal)
        self._params = Params(cfg, self._lock, self._journal, self._link)
        self._dynamics = Dynamics(self._lock, self._journal, ceiling=lambda: self._params.get("LNDMC_ALT_MAX"),
                                  wobble_deg=cfg.hover_wobble_deg, seed=cfg.seed,
                                  heading_rad=math.radians(cfg.heading_deg))
        self._offboard = Offboard(cfg, self._lock, self._journal, self._link, self._dynamics)
        self._estimator = Estimator(cfg, self._lock)
        self._payload = Payload(self._lock, self._journal, announce=self._announce_trigger)
        self._battery = Battery(self._lock, self._journal, self._params, cfg.battery_drop)
        self._datalink = Datalink(self._lock)
        if cfg.link_loss is not None:   # the fault mavlink-loss: the flight link falls silent for a while
            # Counted from liftoff with the link heard: a link no heartbeat came on has nothing to lose (the
            # companion may arm before its first one, and PX4's datalink-loss failsafe would never act).
            self._link.loss = LinkLoss(*cfg.link_loss, journal=self._journal, clock=lambda: (
                self._dynamics.sim_time, self._dynamics.airborne and self._datalink.heard()))
        enc = self._link.encoder
        self._mission = Mission(self._lock, self._params, (cfg.home_lat, cfg.home_lon, cfg.home_alt_m),
                                on_reached=lambda seq: self._link.send(enc.mission_item_reached_encode(seq)),
                                on_current=lambda seq: self._link.send(self._telemetry.mission_current()))
        self._missions = MissionService(self._lock, self._journal, self._link, self._mission)
        self._autopilot = Autopilot(self._lock, self._journal, self._dynamics, self._params, self._offboard,
                                    self._battery, self._datalink, self._mission, cruise_speed_m_s=min(cfg.cruise_speed_m_s, cfg.max_speed_m_s),
                                    estimator=self._estimator, payload=self._payload, gps=cfg.gps,
                                    ready_after_s=cfg.ready_after_s)
        self._telemetry = Telemetry(cfg, self._lock, self._journal, self._link, self._dynamics, self._autopilot,
                                    self._battery, self._mission, self._estimator)
        self._commands = Commands(cfg, self._link, self._journal, self._autopilot, self._telemetry, self._params,
                                  self._offboard, self._datalink, self._mission, self._missions)

    # --- lifecycle -------------------------------------------------------------------

    def start(self) -> "Vehicle":
        """Open the MAVLink link and start the receive, physics and telemetry threads."""
        if self._threads:
            raise MissionError("vehicle already started")
        self._link.open()
        self._journal.speaker = self._link.say
        self._stop.clear()
        self._telemetry.restart_clock()
        self._journal.event("booted")
        loops = (("recv", self._link.run, (self._stop, self._commands.handle, self._telemetry.heartbeat)),
                 ("physics", self._dynamics.run, (self._stop, self.config.time_scale, self._autopilot)),
                 ("telemetry", self._telemetry.run, (self._stop,)),
                 ("missions", self._tick_missions, ()))
        for name, target, args in loops:
            thread = threading.Thread(target=target, args=args, name=f"vehicle-{name}", daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def _announce_trigger(self, trigger: Trigger) -> None:
        """A camera trigger, as PX4's camera_trigger announces it: CAMERA_TRIGGER on every link."""
        self._link.send(self._link.encoder.camera_trigger_encode(int(trigger.time_s * 1e6), trigger.seq))

    def _tick_missions(self) -> None:
        """Drive the mission protocol's retries and timeouts (wall time, like the ground station's)."""
        while not self._stop.wait(0.05):
            self._missions.tick(time.monotonic())

    def stop(self) -> None:
        """Stop the threads (joined within 2 s) and close the link. Idempotent."""
        self._stop.set()
        deadline = time.monotonic() + 2.0
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        self._threads = []
        self._journal.speaker = None
        self._link.close()
        self._journal.warn.flush()   # the warnings held back, said now rather than at exit

    def land_now(self, why: str) -> None:
        """Land where it is if in the air (a failsafe's landing, kept until disarmed)."""
        self._autopilot.land_now(why)

    def __enter__(self) -> "Vehicle":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- public state ----------------------------------------------------------------

    def pose(self) -> tuple[float, float, float, float]:
        """(north, east, down, yaw_rad) in the local NED frame."""
        return self._dynamics.pose()

    def state(self) -> State:
        """Position, velocity and attitude at one instant (NED, m/s, radians)."""
        return self._dynamics.state()

    @property
    def armed(self) -> bool:
        return self._autopilot.armed

    @property
    def landed_state(self) -> LandedState:
        return self._autopilot.landed_state

    @property
    def in_air(self) -> bool:
        return self.landed_state != LandedState.ON_GROUND

    @property
    def mode(self) -> Mode:
        return self._autopilot.mode

    @property
    def bad_frames(self) -> int:
        """Datagrams or frames received that were not valid MAVLink, or that broke a handler."""
        return self._link.bad_frames

    @property
    def refused_strangers(self) -> int:
        """Valid frames the flight link refused because they came from another process than its companion."""
        return self._link.refused_strangers

    @property
    def companion(self) -> tuple[int, object] | None:
        """(system id, address) of the system the flight link answers, once it has spoken."""
        return self._link.companion

    @property
    def camera_triggers(self) -> list[Trigger]:
        """Every camera trigger a mission's camera items made (time, position), oldest first."""
        with self._lock:
            return list(self._payload.triggers)

    @property
    def gimbal_deg(self) -> tuple[float, float]:
        """(pitch, yaw) in degrees the mission last commanded the gimbal to (the camera itself is body-fixed)."""
        with self._lock:
            return self._payload.gimbal_deg

    @property
    def failsafe_kept(self) -> tuple[Mode, str] | None:
        """The battery failsafe's RTL or LAND and its reason while it is kept (commands that would leave it are denied)."""
        return self._autopilot.kept

    @property
    def refused_setpoints(self) -> int:
        """Offboard setpoints refused as not flyable (each reason said once as STATUSTEXT)."""
        return self._offboard.refused

    @property
    def refused_unsigned(self) -> int:
        """Frames the signed ground-station link refused (unsigned or wrongly signed)."""
        return self._link.refused_unsigned

    @property
    def statustexts(self) -> list[tuple[int, str]]:
        """(MAV_SEVERITY, text) of every STATUSTEXT the vehicle sent, oldest first."""
        return self._journal.said

    @property
    def battery_remaining(self) -> float:
        """Fraction of the battery's capacity left, 0..1."""
        return self._battery.remaining

    def param(self, name: str) -> float:
        return self._params.get(name)

    def set_param(self, name: str, value: float) -> float:
        """Set a parameter as PARAM_SET would (within its range); returns the value stored."""
        self._params.set(name, value)
        return self._params.get(name)

    def address(self, link: str = "vehicle") -> tuple[str, int] | None:
        """The (host, port) the `vehicle` or `gcs` link's UDP socket is bound to, once started."""
        return self._link.address(link)

    @property
    def max_altitude_m(self) -> float:
        return self._dynamics.max_altitude

    @property
    def sim_time_s(self) -> float:
        return self._dynamics.sim_time

    @property
    def events(self) -> list[tuple[float, str]]:
        """(simulated time in s, text) of notable events: armed, takeoff, landed, ..."""
        return self._journal.events

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The (host, port) the vehicle's UDP socket is bound to, once started."""
        return self._link.local_address
