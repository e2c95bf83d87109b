"""`uav-robots run`: start the world, the UAV and the robot processes on this machine, watch them, clean up.

Every run gets its own free TCP port (Zenoh), free UDP port (MAVLink) and fleet
prefix, so several runs and test sessions share one machine. Children die with
the launcher (PR_SET_PDEATHSIG), and Ctrl-C or any failing part stops them all.

Every stop is bounded and keeps the evidence: the UAV is stopped first (SIGTERM, then UAV_STOP_S to land
its vehicle and write its report while the world still runs), then the others; every process leaves its
log in OUT/logs/ (the UAV's output also on the terminal); the launcher writes what it can (the report's
additions, or a report of its own when the UAV wrote none; the recording so far; report.html) and says
in one line what it could not. The UAV and the world run in sessions of their own, so that a Ctrl-C at
the terminal reaches the launcher alone, which stops them in that order.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from protocol.errors import MissionError, UavRobotsError
from protocol.keys import format_ids, new_fleet_name
from protocol.process import die_with_parent
from protocol.security import robot_identity
from robot_agents import forked
from robot_agents.faults import parse_fault
from sim_world.faults import is_world_fault

from . import outputs
from .camera_wiring import camera_wiring
from .tee import Tee

GRACE_S = 3.0
# The UAV, told to stop (SIGTERM), writes its report and lands its vehicle (its own bound: 10 s) before
# it exits; after this long it is killed, and the launcher writes the report it could not.
UAV_STOP_S = 15.0
VEHICLE_STOP_S = 100.0   # our vehicle, told to stop in the air, lands first (vehicle_cli.LAND_ON_STOP_S)
DEFAULT_GEOFENCE_M = 1000.0   # the vehicle's GF_MAX_HOR_DIST unless told otherwise
# Robots are not needed before the first plan; 50 Python start-ups at once would starve the
# world's and the UAV's on a small machine, so they start once the UAV flies (its pose feed
# runs), and at the latest this long after the UAV.
ROBOTS_AT_LATEST_S = 8.0


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class Child:
    name: str
    proc: subprocess.Popen | forked.Forked
    log: Path | None
    tee: Tee | None = None       # its output, copied to the terminal and its log

    def tail(self, lines: int = 3) -> str:
        if self.log is None or not self.log.exists():
            return ""
        text = self.log.read_text(errors="replace").strip().splitlines()
        return " | ".join(text[-lines:])


def mavsdk_url(url: str) -> str:
    """A MAVLink link as MAVSDK opens it: pymavlink's spelling (udpin:HOST:PORT, tcp:HOST:PORT) too."""
    if "://" in url:
        return url
    kind, sep, rest = url.partition(":")
    scheme = {"udpin": "udpin", "udp": "udpin", "udpout": "udpout", "tcp": "tcpout", "tcpin": "tcpin"}.get(kind)
    return f"{scheme}://{rest}" if sep and scheme else url


def robot_groups(n: int, per_process: int | None) -> list[list[int]]:
    """One process per robot for small fleets; pools beyond (one process per robot stops scaling near 100)."""
    if per_process is None:
        per_process = 1 if n <= 64 else math.ceil(n / 4)
    per_process = max(1, per_process)
    return [list(range(i, min(n, i + per_process))) for i in range(0, n, per_process)]


class Launcher:
    def __init__(self, args) -> None:
        self.args = args
        self.children: list[Child] = []
        self.fleet = new_fleet_name()
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.udp = free_port(socket.SOCK_DGRAM)        # the UAV's MAVLink port: the vehicle sends there
        self.pose_udp = free_port(socket.SOCK_DGRAM)   # the world's: the vehicle's pose link sends there
        self.floor_shape: tuple[int, ...] | None = None   # the map's, for the vehicle's geofence
        # Without --out the outputs are temporary, unless the run fails: then they are what the user needs.
        self.temporary = not args.out
        self.out = Path(args.out).resolve() if args.out else Path(tempfile.mkdtemp(prefix="uav-robots-"))
        if not self.temporary and self.out.is_dir():
            removed = outputs.clear_earlier(self.out)
            if removed:
                print(f"uav-robots: removed the earlier run's outputs from {self.out}: {', '.join(removed)}",
                      file=sys.stderr, flush=True)
        self.logs = self.out / outputs.LOGS
        self.logs.mkdir(parents=True, exist_ok=True)
        self.stop_reason = ""         # why the launcher stopped the mission, if it did
        self.signalled: int | None = None   # the signal that told the launcher to stop
        self.hurry = threading.Event()      # a second signal: no more waiting for anyone
        self.stopping = False               # the stop has begun: any signal now hurries it
        self.groups = robot_groups(args.robots, args.robots_per_process)
        self.compiler: subprocess.Popen | None = None   # the planners' kernels, on a fresh clone
        self.robots_started = False
        self.robots_due = math.inf
        self.secure_dir: Path | None = None       # certificates and configs, with --secure
        self.secure_temporary = False
        self.configs: dict[str, str] = {}           # identity -> its Zenoh config, with --secure
        if args.secure is not None:
            self._secure(args.secure)

    def _secure(self, given: str) -> None:
        """Mutual TLS and access control: every process gets its own config, certificate and key."""
        from .secure_cli import make_fleet_dir, new_fleet, read_fleet_dir

        port = free_port()
        if given:
            self.secure_dir = Path(given).resolve()
            fleet = read_fleet_dir(self.secure_dir)
            self.fleet, self.groups = fleet.fleet, fleet.groups
            self.configs = {n.name: str(fleet.config(n.name)) for n in fleet.identities()}
        else:
            # Never beside the outputs a failed run keeps: keys leave with the run unless --out asks for them.
            self.secure_temporary = not self.args.out
            self.secure_dir = self.out / "secure" if self.args.out else Path(tempfile.mkdtemp(prefix="uav-robots-secure-"))
            fleet = new_fleet(self.fleet, self.args.robots, self.groups, ["127.0.0.1"], port, self.secure_dir)
            make_fleet_dir(self.secure_dir, fleet)
            self.configs = {n.name: str(self.secure_dir / f"{n.name}.json5") for n in fleet.identities()}
        self.endpoint = f"tls/127.0.0.1:{port}"

    def session_args(self, name: str, hub: bool = False) -> list[str]:
        """How one process opens its session: plain TCP, or its own secure config on this run's port."""
        flag = "--listen" if hub else "--connect"
        if self.secure_dir is None:
            return [flag, self.endpoint]
        return ["--zenoh-config", self.configs[name], flag, self.endpoint]

    def cleanup(self) -> None:
        if self.secure_temporary and self.secure_dir is not None:
            shutil.rmtree(self.secure_dir, ignore_errors=True)

    def _spawn(self, name: str, package: str, argv: list[str], terminal: bool = False) -> Child:
        """A child with its output in logs/NAME.log, and with `terminal` on ours as well."""
        log = self.logs / f"{name}.log"
        if package == "robot_agents" and forked.available():
            child = Child(name, forked.Forked(argv, str(log)), log)
            self.children.append(child)
            return child
        out = None if terminal else open(log, "wb")
        # The robots share the launcher's process group; the UAV and the world get sessions of their
        # own, so that Ctrl-C reaches only the launcher, which stops the UAV first (it lands).
        proc = subprocess.Popen([sys.executable, "-m", package, *argv],
                                stdout=subprocess.PIPE if terminal else out,
                                stderr=subprocess.PIPE if terminal else subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"} if terminal else None,
                                start_new_session=package != "robot_agents", preexec_fn=die_with_parent)
        if out:
            out.close()
        tee = Tee(log, [(proc.stdout, sys.stdout), (proc.stderr, sys.stderr)]) if terminal else None
        child = Child(name, proc, log, tee)
        self.children.append(child)
        return child

    def records(self) -> bool:
        """Whether the launcher's observer can join: a --secure fleet needs its listen-only identity."""
        return self.secure_dir is None or Path(self.configs.get("observer", "")).is_file()

    def start(self) -> Child:
        """Starts the UAV and the world (`start_robots` the robots)."""
        from uav_agent.planning import warm

        a = self.args
        common = ["--fleet", self.fleet]
        # First, so that the compile overlaps every other process's start-up.
        self.compiler = warm.start(a.planner, a.connectivity)
        self.start_vehicle()
        camera_world, camera_uav = camera_wiring(getattr(a, "camera_source", "zenoh"),
                                                 lambda: free_port(socket.SOCK_DGRAM))
        uav = self._spawn("uav", "uav_agent", [*camera_uav, *common, *self.session_args("uav", hub=True), "--robots", str(a.robots),
                                  "--mavlink", self.autopilot_url(), "--out", str(self.out),
                                  *(["--assign", a.assign] if a.assign else []),
                                  "--connectivity", str(a.connectivity),
                                  "--time-limit", str(a.time_limit), "--seed", str(a.seed),
                                  "--tick-rate", str(a.tick_rate), "--tick-timeout", str(a.tick_timeout),
                                  *(["--monitor-every", str(a.monitor_every)] if a.monitor_every is not None else []),
                                  *(["--planner", a.planner] if a.planner else []),
                                  *(["--no-fallback"] if a.no_fallback else []),
                                  *(["--quiet"] if a.quiet or a.json else []),
                                  *(["--observers", "1"] if self.records() else []),
                                  *(["--summary", "none"] if a.json else [])], terminal=True)
        self._spawn("world", "sim_world", [*common, *self.session_args("world"), "--map", a.map,
                              "--robots", str(a.robots), "--seed", str(a.seed),
                              "--connectivity", str(a.connectivity),
                              *self.follow_args(), "--time-scale", str(a.time_scale),
                              *(["--camera", a.camera] if a.camera else []),
                              "--mavlink-bind", a.mavlink_bind, *camera_world,
                              *[x for f in a.fault if is_world_fault(f) for x in ("--fault", f)]])
        self.robots_due = time.monotonic() + ROBOTS_AT_LATEST_S
        return uav

    def start_vehicle(self) -> Child | None:
        """Our simulated autopilot as a process of its own, as a SITL binary (none with --autopilot): the UAV
        flies it on its MAVLink port, the world follows its pose on a third link, the same path as with
        any autopilot's telemetry."""
        from sim_world.camera import CameraModel
        from sim_world.camera.model import camera_options
        from sim_world.config import DRONE_CAMERA, fence_reach_m

        a = self.args
        if getattr(a, "autopilot", None):
            return None
        wobble = CameraModel(**{**DRONE_CAMERA, **camera_options(a.camera)}).wobble_deg
        reach = fence_reach_m(self.floor_shape, 1.0) if self.floor_shape is not None else 0.0
        return self._spawn("vehicle", "sim_world.vehicle", [
            "--mavlink", f"udpout:127.0.0.1:{self.udp}", "--pose-link", f"udpout:127.0.0.1:{self.pose_udp}",
            "--time-scale", str(a.time_scale), "--seed", str(a.seed), "--wobble", str(wobble),
            "--preset", getattr(a, "vehicle_preset", "outdoor"),
            # The geofence must not cut off part of a large floor (the vehicle's default covers 1 km).
            *(["--param", f"GF_MAX_HOR_DIST={reach:.1f}"] if reach > DEFAULT_GEOFENCE_M else []),
            *(["--gcs", a.gcs] if a.gcs else []),
            *(["--mavlink-key", a.mavlink_key] if a.mavlink_key else []),
            "--mavlink-bind", a.mavlink_bind])

    def autopilot_url(self) -> str:
        """The UAV's MAVLink link (MAVSDK's spelling): --autopilot's, or where our vehicle sends."""
        given = getattr(self.args, "autopilot", None)
        return mavsdk_url(given) if given else f"udpin://127.0.0.1:{self.udp}"

    def follow_args(self) -> list[str]:
        """The world flies no vehicle: it follows the autopilot's pose (--autopilot-pose, or our vehicle's)."""
        a = self.args
        pose = getattr(a, "autopilot_pose", None) or f"udpin:127.0.0.1:{self.pose_udp}"
        origin = getattr(a, "autopilot_origin", None)
        if origin is None and getattr(a, "vehicle_preset", "outdoor") == "indoor" and not getattr(a, "autopilot", None):
            origin = "0,0,0"   # our indoor vehicle's local frame starts where home would be: the floor's corner
        return ["--autopilot-pose", pose, *(["--autopilot-origin", origin] if origin else [])]

    def start_robots(self) -> None:
        if self.robots_started:
            return
        self.robots_started = True
        a = self.args
        common = ["--fleet", self.fleet]
        faults = [parse_fault(f) for f in a.fault if not is_world_fault(f)]
        for group in self.groups:
            contiguous = group == list(range(group[0], group[-1] + 1))
            ids = f"{group[0]}-{group[-1]}" if contiguous else format_ids(group)
            mine = [arg for f in faults if f.robot in group for arg in ("--fault", str(f))]
            self._spawn(f"robots-{group[0]}-{group[-1]}", "robot_agents", [*common, *self.session_args(robot_identity(group).name),
                                          "--ids", ids, "--moves", "ahead",
                                          "--connectivity", str(a.connectivity), *mine])

    def watch(self, uav: Child, timeout_s: float, flying=lambda: True, each=lambda: None) -> int | None:
        """Wait for the UAV: it owns the mission's outcome. Other processes dying is the UAV's to
        handle (a lost robot is replanned around); the launcher only says so. The robots start once
        `flying()` (or at the latest ROBOTS_AT_LATEST_S after the UAV); `each()` runs on every look.
        Returns the UAV's exit code, or None when the mission must be stopped (`stop_reason` says why:
        the world died, which leaves the UAV blind; the timeout; a signal to the launcher)."""
        deadline = time.monotonic() + timeout_s
        said: set[str] = set()
        world_gone: float | None = None
        while True:
            code = uav.proc.poll()
            if code is not None:
                return code
            if world_gone is not None and time.monotonic() > world_gone + GRACE_S:
                return None   # the UAV did not notice by itself (it then writes its own reason): it is told
            if self.signalled is not None:
                self.stop_reason = f"{signal.Signals(self.signalled).name} to the launcher"
                return None
            each()
            if not self.robots_started and (flying() or time.monotonic() >= self.robots_due):
                self.start_robots()
            for c in self.children:
                if c is not uav and c.name not in said and c.proc.poll() not in (None, 0):
                    said.add(c.name)
                    print(f"uav-robots: {c.name} process exited with code {c.proc.returncode}: {c.tail()}",
                          file=sys.stderr, flush=True)
                    if c.name == "world":
                        self.stop_reason = f"the world process exited with code {c.proc.returncode}"
                        world_gone = time.monotonic()
            if time.monotonic() > deadline:
                self.stop_reason = f"the mission did not finish within {timeout_s:g} s"
                print(f"error: {self.stop_reason}", file=sys.stderr, flush=True)
                return None
            time.sleep(0.05)

    def stop(self, graceful: bool) -> None:
        """The UAV first, while the world and the robots still run: told to stop (SIGTERM) it writes its
        report and lands its vehicle, within UAV_STOP_S. Then the others: on their own if `graceful`
        (they exit at the mission's end), else SIGTERM, then SIGKILL. Every wait is bounded, and a
        second signal to the launcher (`hurry`) cuts them short."""
        uav = [c for c in self.children if c.name == "uav"]
        if uav and uav[0].proc.poll() is None:
            print(f"uav-robots: stopping the UAV ({self.stop_reason or 'the launcher failed'}): it writes its "
                  f"report and lands, {UAV_STOP_S:g} s at most", file=sys.stderr, flush=True)
        self._end(uav, graceful, UAV_STOP_S)
        # An autopilot never ends on its own: the UAV is done with it. Still in the air (the UAV died), it
        # lands before it stops, and is given the time to.
        vehicle = [c for c in self.children if c.name == "vehicle"]
        self._end(vehicle, False, VEHICLE_STOP_S)
        self._end([c for c in self.children if c.name not in ("uav", "vehicle")], graceful, GRACE_S)
        for c in uav:
            if c.tee is not None:
                c.tee.join(2.0)   # its last lines (a grandchild holding the pipes open is not waited for)
        if self.compiler is not None:
            from uav_agent.planning import warm

            warm.stop(self.compiler)   # what it compiled so far is cached; the next run goes on from there

    def _end(self, children: list[Child], graceful: bool, term_s: float) -> None:
        self._wait(children, GRACE_S if graceful else 0.0)
        for c in children:
            if c.proc.poll() is None:
                c.proc.send_signal(signal.SIGTERM)
        self._wait(children, term_s)
        for c in children:
            if c.proc.poll() is None:
                why = "no more waiting" if self.hurry.is_set() else f"it did not stop within {term_s:g} s of SIGTERM"
                print(f"uav-robots: {c.name} killed: {why}", file=sys.stderr, flush=True)
                c.proc.kill()
                try:
                    c.proc.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    print(f"uav-robots: {c.name} (pid {c.proc.pid}) still runs after SIGKILL", file=sys.stderr,
                          flush=True)

    def _wait(self, children: list[Child], seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while (time.monotonic() < deadline and not self.hurry.is_set()
               and any(c.proc.poll() is None for c in children)):
            time.sleep(0.05)

    def on_signal(self, signum: int, frame: object) -> None:
        """SIGTERM or SIGINT: the first stops the mission in order (`watch` sees it), another, or one
        once the stop has begun, hurries the stop (and skips what is left to draw)."""
        first = self.signalled is None
        if first:
            self.signalled = signum
        if first and not self.stopping:
            print(f"uav-robots: {signal.Signals(signum).name}: stopping every process", file=sys.stderr, flush=True)
        elif not self.hurry.is_set():
            self.hurry.set()
            print(f"uav-robots: {signal.Signals(signum).name} again: no more waiting, killing what still runs",
                  file=sys.stderr, flush=True)

    def pids(self) -> dict:
        by = {c.name: c.proc.pid for c in self.children}
        return {"uav": by.get("uav"), "world": by.get("world"), "vehicle": by.get("vehicle"),
                "robots": [c.proc.pid for c in self.children if c.name.startswith("robots-")],
                "launcher": os.getpid(), "compiler": self.compiler.pid if self.compiler is not None else None}

    def exit_codes(self) -> dict[str, int | None]:
        """Each process's exit code (negative: the signal that ended it; None: it still ran)."""
        return {c.name: c.proc.poll() for c in self.children}


def _number(name: str, value: float, lo: float, hi: float, lo_open: bool = False) -> None:
    ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        raise UavRobotsError(f"{name} must be a number in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {value:g}")


def check_autopilot(args) -> None:
    """--autopilot and --autopilot-pose go together, and leave our vehicle's options out; the time scale
    defaults to our vehicle's 10, or 1 for another autopilot (its clock runs at its own pace)."""
    from sim_world.pose_follower import check_pose_url, parse_origin

    given, pose = getattr(args, "autopilot", None), getattr(args, "autopilot_pose", None)
    if getattr(args, "time_scale", None) is None:
        args.time_scale = 1.0 if given else 10.0
    if bool(given) != bool(pose):
        raise UavRobotsError("--autopilot URL (the UAV's link) and --autopilot-pose URL (the world's) go together")
    if getattr(args, "autopilot_origin", None) is not None and not pose:
        raise UavRobotsError("--autopilot-origin places a followed autopilot: give --autopilot-pose URL too")
    if not given:
        return
    if args.gcs or args.mavlink_key or getattr(args, "vehicle_preset", "outdoor") != "outdoor":
        raise UavRobotsError("--gcs, --mavlink-key and --vehicle-preset configure our vehicle, which --autopilot "
                             "replaces: give a ground station its link on the autopilot itself")
    check_pose_url(pose, args.mavlink_bind)
    parse_origin(args.autopilot_origin)


def check_arguments(args) -> tuple[str, object]:
    """Every input of `run`, checked before any process starts: one line and exit 2 for the first bad one."""
    from protocol.bounds import MAX_ROBOTS
    from scenarios.limits import check_fleet, check_floor
    from scenarios.maps import place, resolve_map
    from sim_world.camera import CameraModel
    from sim_world.camera.model import camera_options
    from sim_world.config import DRONE_CAMERA, MOVE_BATCH_TIMEOUT_S, WorldConfig, vehicle_config
    from sim_world.faults import world_faults

    _number("--robots", args.robots, 1, MAX_ROBOTS)
    check_fleet(args.robots)
    if getattr(args, "view", None) is not None:
        _number("--view", args.view, 0, 65535)
    if getattr(args, "view_hold", None) is not None:
        _number("--view-hold", args.view_hold, 0, 7 * 86400)
    _number("--seed", args.seed, 0, 2**32 - 1)
    check_autopilot(args)
    _number("--time-scale", args.time_scale, 0, 1000, lo_open=True)
    _number("--tick-rate", args.tick_rate, 0, 1000)
    _number("--timeout", args.timeout, 0, 7 * 86400, lo_open=True)
    _number("--time-limit", args.time_limit, 0, 86400, lo_open=True)
    if args.robots_per_process is not None:
        _number("--robots-per-process", args.robots_per_process, 1, MAX_ROBOTS)
    if args.monitor_every is not None:
        _number("--monitor-every", args.monitor_every, 0, 10**6)
    # Everyone waits for the world's batch when one robot is silent: a shorter deadline would call the
    # whole fleet stalled.
    _number("--tick-timeout", args.tick_timeout, MOVE_BATCH_TIMEOUT_S, 3600, lo_open=True)
    if args.out:
        out = Path(args.out)
        try:
            if out.exists() and not out.is_dir():
                raise UavRobotsError(f"--out {args.out}: is a file, not a directory")
            parent = next((p for p in [out, *out.resolve().parents] if p.exists()), None)
        except (OSError, ValueError) as exc:   # a name too long, a NUL byte
            raise UavRobotsError(f"--out {args.out[:80]!r}: not a directory name this system takes "
                                 f"({getattr(exc, 'strerror', None) or exc})") from None
        if parent is not None and not parent.is_dir():   # --out FILE/sub
            raise UavRobotsError(f"--out {args.out}: {parent} is a file, not a directory")
        if parent is None or not os.access(parent, os.W_OK):
            raise UavRobotsError(f"--out {args.out}: cannot write there")
    try:
        CameraModel(**{**DRONE_CAMERA, **camera_options(args.camera)})
    except (MissionError, TypeError) as exc:
        raise UavRobotsError(f"--camera {args.camera!r}: {exc}") from None
    for r in world_faults([f for f in args.fault if is_world_fault(f)]).skids:
        if r >= args.robots:
            raise UavRobotsError(f"--fault skid:{r}@...: there is no robot {r} in a fleet of {args.robots}")
    if not args.autopilot:
        vehicle_config(WorldConfig(fleet="check", gcs=args.gcs, mavlink_key=args.mavlink_key,
                                   mavlink_bind=args.mavlink_bind))
    for f in map(parse_fault, (f for f in args.fault if not is_world_fault(f))):
        if f.robot >= args.robots:
            raise UavRobotsError(f"--fault {f}: there is no robot {f.robot} in a fleet of {args.robots}")
    if args.planner:
        from uav_agent.planning.registry import get_planner

        get_planner(args.planner)
    if args.secure:
        from .secure_cli import read_fleet_dir

        made = read_fleet_dir(Path(args.secure))
        if made.robots != args.robots:
            raise UavRobotsError(f"--secure {args.secure} was made for {made.robots} robots: give --robots {made.robots}")
    elif args.secure is not None:
        from .secure_cli import MAX_ROBOT_PROCESSES

        if len(robot_groups(args.robots, args.robots_per_process)) > MAX_ROBOT_PROCESSES:
            raise UavRobotsError(f"--secure: at most {MAX_ROBOT_PROCESSES} robot processes (identities); "
                                 f"host more robots per process (--robots-per-process)")
    name, free = resolve_map(args.map, args.seed, check_floor)
    place(free, args.robots, args.seed)
    return name, free


def start_observer(launcher: Launcher):
    """The recorder: a Zenoh client of the fleet, connected to the UAV's endpoint (the UAV listens)."""
    from .observer import Observer

    if not launcher.records():
        print("uav-robots: no recording: this --secure directory has no observer identity "
              "(make a new one with `uav-robots secure init`)", file=sys.stderr, flush=True)
        return None
    try:
        return Observer(launcher.endpoint, launcher.fleet, config_file=launcher.configs.get("observer"))
    except MissionError as exc:
        print(f"uav-robots: no recording: {exc}", file=sys.stderr, flush=True)
        return None


def open_view(args, free):
    """The live view's server, up before any process starts so a busy port is bad input, not a lost view."""
    if args.view is None:
        return None
    from .view import LiveView

    try:
        view = LiveView(args.view, free)
    except OSError as exc:
        raise UavRobotsError(f"--view {args.view}: cannot serve there: {exc.strerror or exc}") from None
    print(f"uav-robots: live view at {view.url}", flush=True, file=sys.stderr if args.json else sys.stdout)
    return view


def write_views(out: Path, samples: list, fleet: str, rows: list[str], quiet: bool, ahead=None,
                video: bool = True, cancel: threading.Event | None = None) -> list[str]:
    """report.html, mission.mcap and, if `video`, replay.mp4 (from the recording, as `uav-robots replay`
    makes it, up to the mission's last tick; the one `ahead` (a VideoAhead) drew while the vehicle
    landed, if the recording draws the same), each whole or not at all. `rows`: the floor, where the
    report has none. Returns what could not be written, each with why."""
    from uav_agent.mission import load_report

    from . import recording, replay, report_html

    failed: list[str] = []
    try:
        report = load_report(out)
    except (OSError, ValueError) as exc:   # the UAV's details.json or plan.json (a full disk): without them
        failed.append(f"the report's details ({_why(exc)})")
        report = json.loads((out / outputs.REPORT).read_text())
    try:
        report_html.write(out, report)
    except Exception as exc:  # noqa: BLE001 - the report is written; say what is missing
        failed.append(f"{report_html.REPORT_HTML} ({_why(exc)})")
    rows = (report.get("truth") or {}).get("rows") or (report.get("plan") or {}).get("map", {}).get("rows") or rows
    cell_m = float((report.get("truth") or {}).get("cell_size_m", 1.0))
    mcap, video_path = out / recording.MCAP, out / replay.VIDEO
    try:
        recording.write_mcap(outputs.partial(mcap), samples, f"uavr/{fleet}", rows, cell_m)
        outputs.partial(mcap).replace(mcap)
    except Exception as exc:  # noqa: BLE001 - as above
        outputs.partial(mcap).unlink(missing_ok=True)
        return failed + [f"{recording.MCAP} ({_why(exc)})"] + ([f"{replay.VIDEO} (no recording)"] if video else [])
    if video:
        try:
            rec = recording.read_mcap(mcap)
            last = recording.last_tick(report, rec)
            dropped = recording.bound(rec, last)
            if dropped:
                print(recording.dropped_line(dropped, last), file=sys.stderr, flush=True)
            if ahead is None or not ahead.take(samples, rows, video_path, last):
                replay.render(rec, outputs.partial(video_path), cancel=cancel)
                outputs.partial(video_path).replace(video_path)
        except Exception as exc:  # noqa: BLE001 - as above
            outputs.partial(video_path).unlink(missing_ok=True)
            failed.append(f"{replay.VIDEO} ({_why(exc)})")
    if not quiet:
        made = [mcap, *([video_path] if video_path.exists() else []), out / report_html.REPORT_HTML]
        print(f"  recording: {made[0]} (Foxglove opens it), " + ", ".join(str(p) for p in made[1:] if p.exists()),
              flush=True)
    return failed


def _why(exc: BaseException) -> str:
    from .replay import Cancelled

    if isinstance(exc, Cancelled):
        return "stopped meanwhile"
    return (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)) or type(exc).__name__


def run(args) -> int:
    name, free = check_arguments(args)
    launcher = Launcher(args)
    launcher.floor_shape = free.shape
    try:
        return _run(args, launcher, name, free)
    finally:
        launcher.cleanup()


def _run(args, launcher: "Launcher", name: str, free) -> int:
    t0 = time.perf_counter()
    if not (args.quiet or args.json):
        print(f"uav-robots: map {name} ({free.shape[1]}x{free.shape[0]}), {args.robots} robots, "
              f"fleet {launcher.fleet}, zenoh {launcher.endpoint}"
              f"{' (mutual TLS, access control)' if launcher.secure_dir else ''}, "
              + (f"autopilot {args.autopilot} (pose {args.autopilot_pose})" if args.autopilot
                 else f"vehicle process, mavlink udp:{launcher.udp}")
              + (f", ground station {args.gcs}" if args.gcs else ""), flush=True)
    observer = ahead = uav = None
    code: int | None = None
    view = open_view(args, free)
    # From here on a signal stops the mission in order (Launcher.on_signal), never in the middle of a step.
    held = {sig: signal.signal(sig, launcher.on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        try:
            uav = launcher.start()
            observer = start_observer(launcher)
            if observer is not None:
                from .video_ahead import VideoAhead
                ahead = VideoAhead(observer, launcher.out, launcher.fleet, free)
            if view is not None and observer is not None:
                view.follow(observer)
            code = launcher.watch(uav, args.timeout, observer.flying if observer is not None else lambda: True,
                                  ahead.poll if ahead is not None else lambda: None)
        except UavRobotsError:
            raise
        except Exception as exc:  # noqa: BLE001 - a failed launch still stops everything and leaves a report
            launcher.stop_reason = f"the launcher failed: {type(exc).__name__}: {exc}"
            print(f"error: {launcher.stop_reason}", file=sys.stderr, flush=True)
        finally:
            launcher.stopping = True
            launcher.stop(graceful=code is not None)
            samples = observer.close() if observer is not None else []
        if launcher.signalled is not None:
            code = 128 + launcher.signalled            # 130 Ctrl-C, 143 SIGTERM
        elif code not in (0, 1, 3):
            code = 1                                   # stopped (the world died, the timeout) or the UAV crashed
        return _finish(args, launcher, uav, code, samples, ahead, view, free, t0)
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)


def _finish(args, launcher: "Launcher", uav: Child | None, code: int, samples: list, ahead, view, free,
            t0: float) -> int:
    """Everything stopped: the report (this run's UAV's with the launcher's additions, or the launcher's
    own), the recording, the video, report.html; each one written whole, or named in one line."""
    from protocol.mapfile import format_rows

    out, quiet = launcher.out, args.quiet or args.json
    report_path = out / outputs.REPORT
    failed: list[str] = []
    report, why = outputs.own_report(out, launcher.fleet)
    uav_code = uav.proc.poll() if uav is not None else None
    uav_ended = "did not start" if uav is None else (f"exited with code {uav_code}" if uav_code is not None
                                                     else "did not end")
    if report is None:
        report = outputs.minimal_report(launcher.fleet, args.robots, f"the UAV {uav_ended} {why}"
                                        + (f"; {launcher.stop_reason}" if launcher.stop_reason else ""))
    report["processes"] = launcher.pids()
    report["exit_codes"] = launcher.exit_codes()
    if launcher.stop_reason:
        report["stopped_by"] = launcher.stop_reason
    report.setdefault("timings", {})["wall_total"] = round(time.perf_counter() - t0, 3)
    wrote = False
    try:
        outputs.write_atomic(report_path, json.dumps(report, indent=1))
        wrote = True
        if report.get("written_by") == "launcher":
            print(f"uav-robots: the UAV {uav_ended} {why}: the launcher wrote {report_path} "
                  "(completed false, outcome aborted)", file=sys.stderr, flush=True)
    except OSError as exc:
        failed.append(f"{outputs.REPORT} ({_why(exc)})")
        if why.startswith("with an unreadable"):
            report_path.unlink(missing_ok=True)   # half a report is no report: never left standing
    for c in launcher.children:
        if c.tee is not None and c.tee.log_error is not None:
            failed.append(f"{c.log.relative_to(out)} ({_why(c.tee.log_error)})")
    kept = not launcher.temporary or code != 0 or bool(failed)
    t_views = time.perf_counter()
    try:
        if kept and wrote:
            failed += write_views(out, samples, launcher.fleet, format_rows(free), quiet, ahead,
                                  video=launcher.signalled is None, cancel=launcher.hurry)
            if launcher.signalled is not None and not quiet:
                print(f"  no replay.mp4: stopped by {signal.Signals(launcher.signalled).name} "
                      f"(`uav-robots replay {out}` draws it from the recording)", flush=True)
    finally:
        if ahead is not None:
            ahead.discard()     # what `write_views` did not take (a failed run keeps no half video)
    views_s = time.perf_counter() - t_views
    if failed:
        print(f"uav-robots: could not write {', '.join(failed)}", file=sys.stderr, flush=True)
        if code in (0, 3):
            code = 1
    if args.json:
        print(json.dumps({**report, "exit_code": code, "out": str(out) if kept else None},
                         separators=(",", ":")), flush=True)
    elif report.get("written_by") != "launcher":
        # The UAV printed the mission's summary; the launcher adds what only it knows.
        print(f"  whole run: {report['timings']['wall_total']:.2f}s wall (process start-up and shut-down "
              f"included), {len(report['processes']['robots'])} robot process(es)"
              + (f"; then {views_s:.2f}s writing the recording, video and report page" if views_s >= 0.01 else "")
              + ("" if kept else "; outputs were temporary: keep them with --out DIR"), flush=True)
    if code != 0:
        what = "report and logs" if wrote else "logs"
        how = ("completed, but not every output was written" if report.get("completed") is True and failed
               else "did not complete")
        print(f"uav-robots: the mission {how} (exit {code}); {what} in {out if kept else launcher.logs}",
              file=sys.stderr, flush=True)
    if not kept:
        shutil.rmtree(out, ignore_errors=True)
    if view is not None and launcher.signalled is None:
        view.hold(args.view_hold)
    elif view is not None:
        view.hold(0)
    return code
