"""`uav-robots run`: start the world, the UAV and the robot processes on this machine, watch them, clean up.

Every run gets its own free TCP port (Zenoh), free UDP port (MAVLink) and fleet
prefix, so several runs and test sessions share one machine. Children die with
the launcher (PR_SET_PDEATHSIG), and Ctrl-C or any failing part stops them all.
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
import time
from dataclasses import dataclass
from pathlib import Path

from protocol.errors import MissionError, UavRobotsError
from protocol.keys import format_ids, new_fleet_name
from protocol.process import die_with_parent
from protocol.security import robot_identity
from robot_agents import forked
from robot_agents.faults import parse_fault

GRACE_S = 3.0
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

    def tail(self, lines: int = 3) -> str:
        if self.log is None or not self.log.exists():
            return ""
        text = self.log.read_text(errors="replace").strip().splitlines()
        return " | ".join(text[-lines:])


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
        self.udp = free_port(socket.SOCK_DGRAM)
        # Without --out the outputs are temporary, unless the run fails: then they are what the user needs.
        self.temporary = not args.out
        self.out = Path(args.out).resolve() if args.out else Path(tempfile.mkdtemp(prefix="uav-robots-"))
        self.logs = self.out / "logs"
        self.logs.mkdir(parents=True, exist_ok=True)
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

    def _spawn(self, name: str, package: str, argv: list[str], to_log: bool) -> Child:
        log = self.logs / f"{name}.log" if to_log else None
        if package == "robot_agents" and forked.available():
            child = Child(name, forked.Forked(argv, str(log) if log else None), log)
            self.children.append(child)
            return child
        out = open(log, "wb") if log else None
        proc = subprocess.Popen([sys.executable, "-m", package, *argv], stdout=out or None,
                                stderr=subprocess.STDOUT if out else None, stdin=subprocess.DEVNULL,
                                preexec_fn=die_with_parent)
        if out:
            out.close()
        child = Child(name, proc, log)
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
        uav = self._spawn("uav", "uav_agent", [*common, *self.session_args("uav", hub=True), "--robots", str(a.robots),
                                  "--mavlink", f"udpin://127.0.0.1:{self.udp}", "--out", str(self.out),
                                  *(["--assign", a.assign] if a.assign else []),
                                  "--connectivity", str(a.connectivity),
                                  "--time-limit", str(a.time_limit), "--seed", str(a.seed),
                                  "--tick-rate", str(a.tick_rate), "--tick-timeout", str(a.tick_timeout),
                                  *(["--monitor-every", str(a.monitor_every)] if a.monitor_every is not None else []),
                                  *(["--planner", a.planner] if a.planner else []),
                                  *(["--no-fallback"] if a.no_fallback else []),
                                  *(["--quiet"] if a.quiet or a.json else []),
                                  *(["--observers", "1"] if self.records() else []),
                                  *(["--summary", "none"] if a.json else [])], to_log=False)
        self._spawn("world", "sim_world", [*common, *self.session_args("world"), "--map", a.map,
                              "--robots", str(a.robots), "--seed", str(a.seed),
                              "--connectivity", str(a.connectivity),
                              "--mavlink", f"udpout:127.0.0.1:{self.udp}", "--time-scale", str(a.time_scale),
                              *(["--camera", a.camera] if a.camera else []),
                              *(["--gcs", a.gcs] if a.gcs else []),
                              *(["--mavlink-key", a.mavlink_key] if a.mavlink_key else []),
                              "--mavlink-bind", a.mavlink_bind,
                              *[x for f in a.fault if f.startswith("slip:") for x in ("--fault", f)]],
                    to_log=True)
        self.robots_due = time.monotonic() + ROBOTS_AT_LATEST_S
        return uav

    def start_robots(self) -> None:
        if self.robots_started:
            return
        self.robots_started = True
        a = self.args
        common = ["--fleet", self.fleet]
        faults = [parse_fault(f) for f in a.fault if not f.startswith("slip:")]
        for group in self.groups:
            contiguous = group == list(range(group[0], group[-1] + 1))
            ids = f"{group[0]}-{group[-1]}" if contiguous else format_ids(group)
            mine = [arg for f in faults if f.robot in group for arg in ("--fault", str(f))]
            self._spawn(f"robots-{group[0]}-{group[-1]}", "robot_agents", [*common, *self.session_args(robot_identity(group).name),
                                          "--ids", ids, "--moves", "ahead",
                                          "--connectivity", str(a.connectivity), *mine], to_log=True)

    def watch(self, uav: Child, timeout_s: float, flying=lambda: True, each=lambda: None) -> int:
        """Wait for the UAV: it owns the mission's outcome. Other processes dying is the UAV's to
        handle (a lost robot is replanned around); the launcher only says so. The world dying leaves
        the UAV blind, so it is told to stop, which lands its vehicle. The robots start once
        `flying()` (or at the latest ROBOTS_AT_LATEST_S after the UAV); `each()` runs on every look."""
        deadline = time.monotonic() + timeout_s
        said: set[str] = set()
        while True:
            code = uav.proc.poll()
            if code is not None:
                return code
            each()
            if not self.robots_started and (flying() or time.monotonic() >= self.robots_due):
                self.start_robots()
            for c in self.children:
                if c is not uav and c.name not in said and c.proc.poll() not in (None, 0):
                    said.add(c.name)
                    print(f"uav-robots: {c.name} process exited with code {c.proc.returncode}: {c.tail()}",
                          file=sys.stderr, flush=True)
                    if c.name == "world":
                        uav.proc.send_signal(signal.SIGTERM)
            if time.monotonic() > deadline:
                raise MissionError(f"mission did not finish within {timeout_s:g} s")
            time.sleep(0.05)

    def stop(self, graceful: bool) -> None:
        """Let children finish on their own (they exit at mission end) if `graceful`, then TERM, then KILL."""
        deadline = time.monotonic() + (GRACE_S if graceful else 0.0)
        while time.monotonic() < deadline and any(c.proc.poll() is None for c in self.children):
            time.sleep(0.05)
        for c in self.children:
            if c.proc.poll() is None:
                c.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + GRACE_S
        while time.monotonic() < deadline and any(c.proc.poll() is None for c in self.children):
            time.sleep(0.05)
        for c in self.children:
            if c.proc.poll() is None:
                c.proc.kill()
                c.proc.wait(timeout=5)
        if self.compiler is not None:
            from uav_agent.planning import warm

            warm.stop(self.compiler)   # what it compiled so far is cached; the next run goes on from there

    def pids(self) -> dict:
        by = {c.name: c.proc.pid for c in self.children}
        return {"uav": by.get("uav"), "world": by.get("world"),
                "robots": [c.proc.pid for c in self.children if c.name.startswith("robots-")],
                "launcher": os.getpid(), "compiler": self.compiler.pid if self.compiler is not None else None}


def _number(name: str, value: float, lo: float, hi: float, lo_open: bool = False) -> None:
    ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        raise UavRobotsError(f"{name} must be a number in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {value:g}")


def check_arguments(args) -> tuple[str, object]:
    """Every input of `run`, checked before any process starts: one line and exit 2 for the first bad one."""
    from protocol.messages import MAX_ROBOTS
    from scenarios.maps import place, resolve_map
    from sim_world.camera import CameraModel
    from sim_world.world import (DRONE_CAMERA, MOVE_BATCH_TIMEOUT_S, WorldConfig, camera_options, slip_probability,
                                 vehicle_config)

    _number("--robots", args.robots, 1, MAX_ROBOTS)
    if getattr(args, "view", None) is not None:
        _number("--view", args.view, 0, 65535)
    if getattr(args, "view_hold", None) is not None:
        _number("--view-hold", args.view_hold, 0, 7 * 86400)
    _number("--seed", args.seed, 0, 2**32 - 1)
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
        if out.exists() and not out.is_dir():
            raise UavRobotsError(f"--out {args.out}: is a file, not a directory")
        parent = next((p for p in [out, *out.resolve().parents] if p.exists()), None)
        if parent is None or not os.access(parent, os.W_OK):
            raise UavRobotsError(f"--out {args.out}: cannot write there")
    try:
        CameraModel(**{**DRONE_CAMERA, **camera_options(args.camera)})
    except (MissionError, TypeError) as exc:
        raise UavRobotsError(f"--camera {args.camera!r}: {exc}") from None
    slip_probability([f for f in args.fault if f.startswith("slip:")])
    vehicle_config(WorldConfig(fleet="check", gcs=args.gcs, mavlink_key=args.mavlink_key,
                               mavlink_bind=args.mavlink_bind))
    for f in map(parse_fault, (f for f in args.fault if not f.startswith("slip:"))):
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
    name, free = resolve_map(args.map, args.seed)
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


def write_views(out: Path, samples: list, fleet: str, quiet: bool, ahead=None) -> None:
    """mission.mcap, replay.mp4 (from the recording, as `uav-robots replay` makes it; the one `ahead`
    (a VideoAhead) drew while the vehicle landed, if the recording draws the same) and report.html."""
    from uav_agent.mission import load_report

    from . import recording, replay, report_html

    report = load_report(out)
    try:
        report_html.write(out, report)
        rows = (report.get("truth") or {}).get("rows") or (report.get("plan") or {}).get("map", {}).get("rows")
        cell_m = float((report.get("truth") or {}).get("cell_size_m", 1.0))
        recording.write_mcap(out / recording.MCAP, samples, f"uavr/{fleet}", rows, cell_m)
        if ahead is None or not ahead.take(samples, rows, out / replay.VIDEO):
            replay.render(recording.read_mcap(out / recording.MCAP), out / replay.VIDEO)
    except Exception as exc:  # noqa: BLE001 - the mission's own report is written; say what is missing
        print(f"uav-robots: could not write the recording or the video: {exc}", file=sys.stderr, flush=True)
        return
    if not quiet:
        print(f"  recording: {out / recording.MCAP} (Foxglove opens it), {out / replay.VIDEO}, "
              f"{out / report_html.REPORT_HTML}", flush=True)


def run(args) -> int:
    name, free = check_arguments(args)
    launcher = Launcher(args)
    try:
        return _run(args, launcher, name, free)
    finally:
        launcher.cleanup()


def _run(args, launcher: "Launcher", name: str, free) -> int:
    t0 = time.perf_counter()
    code = 1
    if not (args.quiet or args.json):
        print(f"uav-robots: map {name} ({free.shape[1]}x{free.shape[0]}), {args.robots} robots, "
              f"fleet {launcher.fleet}, zenoh {launcher.endpoint}"
              f"{' (mutual TLS, access control)' if launcher.secure_dir else ''}, mavlink udp:{launcher.udp}"
              + (f", ground station {args.gcs}" if args.gcs else ""), flush=True)
    observer = ahead = None
    view = open_view(args, free)
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
    except KeyboardInterrupt:
        print("interrupted: stopping every process", file=sys.stderr, flush=True)
        code = 130
    except MissionError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        code = 1
    finally:
        # The UAV has exited (its abort landing included) unless interrupted or timed out.
        launcher.stop(graceful=code in (0, 1, 3))
    report_path = launcher.out / "report.json"
    kept = not launcher.temporary or code != 0
    if report_path.exists():
        report = json.loads(report_path.read_text())
        report["processes"] = launcher.pids()
        report.setdefault("timings", {})["wall_total"] = round(time.perf_counter() - t0, 3)
        report_path.write_text(json.dumps(report, indent=1))
    samples = observer.close() if observer is not None else []
    t_views = time.perf_counter()
    try:
        if kept and report_path.exists():
            write_views(launcher.out, samples, launcher.fleet, quiet=args.quiet or args.json, ahead=ahead)
    finally:
        if ahead is not None:
            ahead.discard()     # what `write_views` did not take (a failed run keeps no half video)
    views_s = time.perf_counter() - t_views
    if args.json:
        summary = report if report_path.exists() else {"completed": False, "outcome": "aborted",
                                                       "reason": f"the UAV exited with code {code}"}
        print(json.dumps({**summary, "exit_code": code if code in (0, 1, 3, 130) else 1,
                          "out": str(launcher.out) if kept else None}, separators=(",", ":")), flush=True)
    elif report_path.exists():
        # The UAV printed the mission's summary; the launcher adds what only it knows.
        print(f"  whole run: {report['timings']['wall_total']:.2f}s wall (process start-up and shut-down "
              f"included), {len(report['processes']['robots'])} robot process(es)"
              + (f"; then {views_s:.2f}s writing the recording, video and report page" if views_s >= 0.01 else "")
              + ("" if kept else "; outputs were temporary: keep them with --out DIR"), flush=True)
    if code not in (0, 130):
        where = launcher.out if kept else launcher.logs
        print(f"uav-robots: the mission did not complete (exit {code}); report and logs in {where}",
              file=sys.stderr, flush=True)
    if not kept:
        shutil.rmtree(launcher.out, ignore_errors=True)
    if view is not None:
        view.hold(args.view_hold)
    return code if code in (0, 1, 3, 130) else 1
