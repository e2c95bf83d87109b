"""A UAV without a working world (none, silent or garbage): how it ends its mission, with no vehicle and no fleet."""
from __future__ import annotations

import subprocess
import time
from pathlib import Path

from protocol.errors import ProtocolError
from protocol.messages import MissionEnd
from protocol.codec import decode
from protocol.transport import Handle, IncomingQuery

from ..hub import Hub
from ..processes import stop_process
from ..waiter import Waiter
from .fleet_state import Observed
from .misbehaviour import Misbehaviour
from .mission import MissionRun
from .options import SETTLE_S, UavOptions
from .processes import free_udp_port, start_process, uav_command


WORLDS = ("none", "silent", "garbage")   # no world; a world that answers world/info nothing; or garbage


class _Watcher(Waiter):
    """What a UAV without a working world puts: its token, its mission end."""

    def __init__(self, hub: Hub) -> None:
        Waiter.__init__(self)
        self.log = Observed()
        t, k = hub.transport, hub.keys
        self.handles = [t.subscribe(k.mission_end, self._on_end), t.watch_alive(k.alive_uav, self._on_uav)]

    def _on_end(self, key: str, payload: bytes) -> None:
        try:
            end = decode(payload, MissionEnd)
        except ProtocolError as exc:
            end = None
            self.log.violations.append(("malformed", f"the UAV put an unreadable message on {key}: {exc}"))
        with self.cv:
            if end is not None:
                self.log.ends.append((time.monotonic(), end))
            self.cv.notify_all()

    def _on_uav(self, _key: str, alive: bool) -> None:
        with self.cv:
            self.log.uav_alive.append((time.monotonic(), alive))
            self.cv.notify_all()

    def close(self) -> None:
        for h in self.handles:
            h.close()


def run_stranded(opts: UavOptions, world: str, workdir: Path, timeout_s: float) -> MissionRun:
    """Start the UAV under test on a router with no world (`none`), or with a world whose token is up
    but which answers `world/info` with nothing (`silent`: the query ends without a reply) or with
    garbage (`garbage`); no vehicle. Run until it exits, at most `timeout_s`."""
    workdir.mkdir(parents=True, exist_ok=True)
    out, err = workdir / "uav.stdout", workdir / "uav.stderr"
    with Hub() as hub:
        handles: list[Handle] = []
        watcher = _Watcher(hub)
        try:
            if world != "none":
                def answer(q: IncomingQuery) -> None:
                    if world == "garbage":
                        q.reply(b'{"type":"WorldInfo","v":1,"width":"wide"}')
                    else:
                        q.finish()
                handles.append(hub.transport.serve(hub.keys.world_info, answer))
                handles.append(hub.transport.announce(hub.keys.alive_world))
            argv = uav_command(opts.cmd, fleet=hub.fleet, endpoint=hub.endpoint, mavlink_port=free_udp_port(),
                               robots=opts.robots, tick_timeout=opts.tick_timeout_s)
            started = time.monotonic()
            proc = start_process(argv, out, err)
            try:
                try:
                    code: int | None = proc.wait(timeout_s)
                except subprocess.TimeoutExpired:
                    code = None
                exited = time.monotonic()
            finally:
                if proc.poll() is None:
                    stop_process(proc)
                    exited = time.monotonic()
            watcher.until(lambda: bool(watcher.log.uav_alive) and not watcher.log.uav_alive[-1][1], SETTLE_S)
        finally:
            watcher.close()
            for h in handles:
                h.close()
        return MissionRun(code=code, started=started, exited=exited, stdout=out.read_text(errors="replace"),
                          stderr=err.read_text(errors="replace"), log=watcher.log, truth=None, record=None,
                          vehicle=None, behaviour=Misbehaviour(), robots=opts.robots)
