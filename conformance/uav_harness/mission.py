"""One mission of the UAV under test: router, world, fleet and UAV started, run to its exit, and what each saw."""
from __future__ import annotations

import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocol.messages import Plan, Record

from ..hub import Hub
from ..processes import stop_process
from .fleet import FakeFleet
from .fleet_state import Observed
from .misbehaviour import Misbehaviour
from .options import LATE_JOIN_S, SETTLE_S, UavOptions
from .processes import start_process, uav_command
from .site import Shutter, Site


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


def error_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]
