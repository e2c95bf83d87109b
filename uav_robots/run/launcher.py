"""The mission's processes: the world, the UAV, its vehicle and the robots, each spawned with its log,
watched while the UAV flies, and stopped in order.

Every run gets its own free TCP port (Zenoh), free UDP port (MAVLink) and fleet
prefix, so several runs and test sessions share one machine. Children die with
the launcher (PR_SET_PDEATHSIG), and Ctrl-C or any failing part stops them all.

Every stop is bounded and keeps the evidence: the UAV is stopped first (SIGTERM, then UAV_STOP_S to land
its vehicle and write its report while the world still runs), then the others; every process leaves its
log in OUT/logs/ (the UAV's output also on the terminal). The UAV and the world run in sessions of their
own, so that a Ctrl-C at the terminal reaches the launcher alone, which stops them in that order.
"""
from __future__ import annotations

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

from protocol.keys import format_ids, new_fleet_name
from protocol.process import die_with_parent
from protocol.security import robot_identity
from robot_agents import forked

from ..common import outputs
from ..common.ports import free_port
from ..common.robot_groups import robot_groups
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
        self.spec: Path | None = None               # OUT/run.json: every process reads the run's configuration there
        self.configs: dict[str, str] = {}           # identity -> its Zenoh config, with --secure
        if args.secure is not None:
            self._secure(args.secure)

    def _secure(self, given: str) -> None:
        """Mutual TLS and access control: every process gets its own config, certificate and key."""
        from ..secure.fleet import make_fleet_dir, new_fleet, read_fleet_dir

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
        from uav_agent.planning.build import warm

        a = self.args
        common = ["--fleet", self.fleet]
        # First, so that the compile overlaps every other process's start-up.
        self.compiler = warm.start(a.planner, a.connectivity)
        self.start_vehicle()
        camera_world, camera_uav = camera_wiring(getattr(a, "camera_source", "zenoh"),
                                                 lambda: free_port(socket.SOCK_DGRAM))
        # The run's configuration is the spec's; the flags here are what is this process's alone.
        uav = self._spawn("uav", "uav_agent", [*camera_uav, *common, *self.session_args("uav", hub=True),
                                  "--spec", str(self.spec), "--mavlink", self.autopilot_url(), "--out", str(self.out),
                                  *(["--quiet"] if a.quiet or a.json else []),
                                  *(["--observers", "1"] if self.records() else []),
                                  *(["--summary", "none"] if a.json else [])], terminal=True)
        self._spawn("world", "sim_world", [*common, *self.session_args("world"), "--spec", str(self.spec),
                              *self.follow_args(), *camera_world])
        self.robots_due = time.monotonic() + ROBOTS_AT_LATEST_S
        return uav

    def start_vehicle(self) -> Child | None:
        """Our simulated autopilot as a process of its own, as a SITL binary (none with --autopilot): the UAV
        flies it on its MAVLink port, the world follows its pose on a third link, the same path as with
        any autopilot's telemetry."""
        from sim_world.config import fence_reach_m

        if getattr(self.args, "autopilot", None):
            return None
        reach = fence_reach_m(self.floor_shape, 1.0) if self.floor_shape is not None else 0.0
        return self._spawn("vehicle", "sim_world.vehicle", [
            "--spec", str(self.spec),
            "--mavlink", f"udpout:127.0.0.1:{self.udp}", "--pose-link", f"udpout:127.0.0.1:{self.pose_udp}",
            # The geofence must not cut off part of a large floor (the vehicle's default covers 1 km).
            *(["--param", f"GF_MAX_HOR_DIST={reach:.1f}"] if reach > DEFAULT_GEOFENCE_M else [])])

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
        common = ["--fleet", self.fleet]
        for group in self.groups:
            contiguous = group == list(range(group[0], group[-1] + 1))
            ids = f"{group[0]}-{group[-1]}" if contiguous else format_ids(group)
            # Each pool takes the faults of the robots it hosts from the spec.
            self._spawn(f"robots-{group[0]}-{group[-1]}", "robot_agents", [*common, *self.session_args(robot_identity(group).name),
                                          "--ids", ids, "--moves", "ahead", "--spec", str(self.spec)])

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
            from uav_agent.planning.build import warm

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
