"""The world's camera follows an autopilot it does not fly: its pose read from MAVLink telemetry.

With `--autopilot-pose URL` the world runs no vehicle of its own. It listens to an autopilot (ours
as `uav-robots vehicle`, PX4 or ArduPilot SITL, a real drone) on a link of its own (a ground
station's port: the UAV agent has the API port), asks it for the streams it needs, and keeps a short
history of the pose in the floor's frame (sim_world/pose_track.py), from which each image is
rendered at its shutter's instant.

Read: HEARTBEAT (which system is the autopilot, armed), LOCAL_POSITION_NED (position, velocity),
ATTITUDE or ATTITUDE_QUATERNION, HOME_POSITION (where the local frame lies), EXTENDED_SYS_STATE
(landed state), STATUSTEXT; GLOBAL_POSITION_INT where there is no LOCAL_POSITION_NED. Asked for:
MAV_CMD_SET_MESSAGE_INTERVAL (PX4, ArduPilot) and REQUEST_DATA_STREAM (ArduPilot streams nothing on a
link until asked), again every second while a stream is missing; never a rate below what the UAV
agent asks (an autopilot whose intervals are not per link would slow the UAV's streams too). It
sends no HEARTBEAT: the autopilot's datalink-loss failsafe must see the UAV's link alone.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Callable

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import MissionError, UavRobotsError

from .pose_track import BootClock, FloorFrame, Pose, Track, Truth, Vec3, euler_of_quaternion

# Asked of the autopilot (message id -> Hz). As fast as the UAV agent asks (mission.TELEMETRY_HZ):
# between two samples the image is interpolated, and a higher rate only costs the link.
STREAMS_HZ = {
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 50.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 50.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 10.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 1.0,
}
LEGACY_STREAMS_HZ = {   # REQUEST_DATA_STREAM, for an ArduPilot that knows no message intervals
    mavlink.MAV_DATA_STREAM_POSITION: 50,     # LOCAL_POSITION_NED, GLOBAL_POSITION_INT
    mavlink.MAV_DATA_STREAM_EXTRA1: 50,       # ATTITUDE
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: 2,
}
ASK_EVERY_S = 1.0        # while a stream is missing, ask again this often
STALE_S = 1.0            # a stream silent this long is missing
SOURCE = (255, mavlink.MAV_COMP_ID_MISSIONPLANNER)   # a ground-station component, as MAVProxy's


def pymavlink_url(url: str) -> str:
    """A link as pymavlink opens it; MAVSDK's spelling (`udpin://host:port`, `udp://:14540`) too."""
    kind, sep, rest = url.partition("://")
    if not sep:
        return url
    if kind == "udp":        # MAVSDK's old spelling of a listening port
        kind = "udpin"
    host, _, port = rest.rpartition(":")
    return f"{kind}:{host or '0.0.0.0'}:{port}"


def _is_loopback(host: str) -> bool:
    from ipaddress import ip_address

    if host == "localhost":
        return True
    try:
        return ip_address(host).is_loopback
    except ValueError:
        return False


def check_pose_url(url: str, bind_host: str) -> str:
    """The pose link's pymavlink URL; one line for a link that would take poses from other hosts
    while the world is bound to loopback (a forged pose would move what the camera sees)."""
    link = pymavlink_url(url)
    kind, _, rest = link.partition(":")
    host = rest.rpartition(":")[0]
    if kind not in ("udpin", "udpout", "udp", "tcpin", "tcp"):
        raise UavRobotsError(f"--autopilot-pose {url!r}: give udpin:HOST:PORT, udpout:HOST:PORT or tcp:HOST:PORT "
                             "(MAVSDK's udpin://HOST:PORT too)")
    if host and _is_loopback(bind_host) and not _is_loopback(host):
        raise UavRobotsError(f"--autopilot-pose {url!r} is not on this machine, but the world is bound to loopback "
                             f"({bind_host}); open it deliberately with --mavlink-bind "
                             f"{host if kind in ('udpin', 'udp', 'tcpin') else '0.0.0.0'}")
    return link


def parse_origin(text: str | None) -> Vec3 | None:
    """`--autopilot-origin`: "home" (None: the autopilot's first home is the floor's corner) or N,E,D."""
    if text is None or text.strip().lower() == "home":
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(map(math.isfinite, values)):
        raise UavRobotsError(f"--autopilot-origin {text!r}: give 'home' or N,E,D (metres on the floor)")
    return values  # type: ignore[return-value]


class PoseFollower:
    """Reads one autopilot's pose on `url` (pymavlink's spelling or MAVSDK's). `start()` opens the
    link (one-line MissionError if it cannot) and runs the reader; `pose_at(t)` is the pose at the
    local monotonic instant `t`; `truth()` what the autopilot showed of itself."""

    def __init__(self, url: str, origin: Vec3 | None = None, bind_host: str = "127.0.0.1",
                 warn: Callable[[str], None] | None = None) -> None:
        self.url = url
        self.link = check_pose_url(url, bind_host)
        self.bind_host = bind_host
        self.warn = warn or (lambda _line: None)
        self.frame = FloorFrame(origin)
        self.track = Track()
        self.clock = BootClock()
        self.status = Truth()
        self.target: tuple[int, int] | None = None     # the autopilot's (system, component)
        self.bad_frames = 0
        self._heard = False                              # anything valid came on the link yet
        self._local_seen = -math.inf                    # when LOCAL_POSITION_NED last came
        self._cv = threading.Condition()
        self._stop = threading.Event()
        self._conn = None
        self._thread: threading.Thread | None = None

    # --- life cycle --------------------------------------------------------------------------

    def start(self) -> "PoseFollower":
        try:
            conn = mavutil.mavlink_connection(self.link, source_system=SOURCE[0], source_component=SOURCE[1])
            if isinstance(conn, mavutil.mavudp) and not conn.udp_server:
                conn.port.bind((self.bind_host, 0))   # else its first send binds 0.0.0.0: any host's poses
        except Exception as exc:  # pymavlink raises anything from ValueError to OSError here
            raise MissionError(f"cannot open the autopilot pose link {self.url!r}: {exc}") from None
        conn.mav.robust_parsing = True
        self._conn = conn
        self._thread = threading.Thread(target=self._run, name="pose-follower", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:
                pass
            self._conn = None

    # --- what the world asks -----------------------------------------------------------------

    def pose_at(self, t: float, wait_s: float = 0.0) -> Pose | None:
        """The pose at the local instant `t` (time.monotonic()); waits up to `wait_s` for the samples
        after it (the telemetry of an instant comes after it), then carries the last one on."""
        deadline = time.monotonic() + wait_s
        with self._cv:
            while not self._covered(t):
                left = deadline - time.monotonic()
                if left <= 0 or self._stop.is_set():
                    break
                self._cv.wait(left)
            return self.track.at(t)

    def _covered(self, t: float) -> bool:
        p, a = self.track.last_position_t, self.track.last_attitude_t
        return p is not None and p >= t and (a is None or a >= t)

    def autopilot_time(self, t: float) -> float | None:
        """The autopilot's clock (s since its boot) at the local instant `t`."""
        with self._cv:
            return self.clock.boot_at(t)

    def truth(self) -> dict:
        """What the autopilot showed of itself, as the world records a vehicle of its own."""
        with self._cv:
            s = self.status
            return {"url": self.url, "source": "telemetry", "armed": s.armed, "landed_state": s.landed_name(),
                    "max_altitude_m": round(s.max_altitude_m, 2), "bad_frames": self.bad_frames,
                    "gcs": None, "refused_unsigned": 0, "events": [[round(t, 2), text] for t, text in s.events]}

    # --- the reader --------------------------------------------------------------------------

    def _run(self) -> None:
        next_ask = 0.0
        while not self._stop.is_set():
            conn = self._conn
            try:
                msg = conn.recv_match(blocking=True, timeout=0.05)
            except Exception as exc:  # noqa: BLE001 - a closed socket, or garbage pymavlink chokes on
                if self._stop.is_set():
                    return
                self.warn(f"autopilot pose link {self.url}: {type(exc).__name__}: {exc}")
                time.sleep(0.05)
                continue
            now = time.monotonic()
            if msg is not None:
                try:
                    self._take(msg, now)
                except Exception as exc:  # noqa: BLE001 - a well-formed frame with absurd content
                    self.bad_frames += 1
                    self.warn(f"autopilot pose link: cannot take {msg.get_type()}: {type(exc).__name__}: {exc}")
            if now >= next_ask:
                next_ask = now + ASK_EVERY_S
                if self._missing(now):
                    self._ask()

    def _missing(self, now: float) -> bool:
        p, a = self.track.last_position_t, self.track.last_attitude_t
        return (self.target is None or not self.frame.known or p is None or a is None
                or min(p, a) < now - STALE_S or self._local_seen < now - STALE_S)

    def _ask(self) -> None:
        """Ask for the streams (everyone's, until the autopilot is known: a udpin autopilot learns of
        this link only from what it receives)."""
        system, component = self.target or (0, 0)
        mav = self._conn.mav
        try:
            for msg_id, hz in STREAMS_HZ.items():
                mav.command_long_send(system, component, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                      msg_id, 1e6 / hz, 0, 0, 0, 0, 0)
            if self.frame.home is None:
                mav.command_long_send(system, component, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                      mavlink.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0)
            for stream, hz in LEGACY_STREAMS_HZ.items():
                mav.request_data_stream_send(system, component, stream, hz, 1)
        except OSError as exc:   # nobody listening yet (an ICMP port unreachable), a closed socket
            self.warn(f"autopilot pose link {self.url}: cannot ask for telemetry: {exc.strerror or exc}")

    def _take(self, msg, now: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.bad_frames += 1
            return
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if not self._heard:   # a listening link (udpin) can answer only now: ask at once, not in a second
            self._heard = True
            self._ask()
        if kind == "HEARTBEAT" and self.target is None and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID:
            self.target = source
            self._ask()
        if source != self.target:
            return   # a ground station, a camera, another vehicle on the same link
        with self._cv:
            self._take_from_autopilot(kind, msg, now)
            self._cv.notify_all()

    def _take_from_autopilot(self, kind: str, msg, now: float) -> None:
        boot = getattr(msg, "time_boot_ms", None)
        t = self.clock.local(boot / 1000.0, now) if boot is not None else now
        t_ap = self.clock.boot_at(now) or 0.0
        s = self.status
        if kind == "HEARTBEAT":
            s.on_armed(bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED), t_ap)
        elif kind == "LOCAL_POSITION_NED":
            self._local_seen = now
            self._position(self.frame.from_local((msg.x, msg.y, msg.z)), (msg.vx, msg.vy, msg.vz), t, boot)
        elif kind == "GLOBAL_POSITION_INT" and self._local_seen < now - STALE_S:
            pos = self.frame.from_global(msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0)
            self._position(pos, (msg.vx / 100.0, msg.vy / 100.0, msg.vz / 100.0), t, boot)
        elif kind == "ATTITUDE":
            self.track.add_attitude(t, msg.roll, msg.pitch, msg.yaw)
        elif kind == "ATTITUDE_QUATERNION":
            self.track.add_attitude(t, *euler_of_quaternion(msg.q1, msg.q2, msg.q3, msg.q4))
        elif kind == "HOME_POSITION":
            if self.frame.on_home(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0, msg.x, msg.y, msg.z):
                s.events.append((t_ap, "the floor's corner pinned at the autopilot's home "
                                       f"{msg.latitude / 1e7:.7f} {msg.longitude / 1e7:.7f} {msg.altitude / 1000.0:.1f} m"))
        elif kind == "EXTENDED_SYS_STATE":
            s.on_landed_state(msg.landed_state, t_ap)
        elif kind == "STATUSTEXT":
            s.on_text(msg.severity, msg.text, getattr(msg, "id", 0), getattr(msg, "chunk_seq", 0), t_ap)

    def _position(self, pos: Vec3 | None, vel: Vec3, t: float, boot: int | None) -> None:
        if pos is None or not all(map(math.isfinite, (*pos, *vel))):
            return   # the floor is not placed yet (no home), or the estimate is not valid
        self.track.add_position(t, pos, vel)
        self.status.on_position(-pos[2], vel[2], boot / 1000.0 if boot is not None else 0.0)
