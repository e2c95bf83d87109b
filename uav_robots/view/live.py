"""`--view`: the mission in a browser, live (`uav-robots run --view`) or recorded (`uav-robots replay DIR --view`).

The live view lives in the launcher's process, fed by its observer: the fleet's processes neither know
nor wait for it.
"""
from __future__ import annotations

import sys
import time

import numpy as np

from .server import Pump, ViewServer
from .state import FleetView


def hold(url: str, seconds: float | None) -> None:
    """Keep serving: `seconds`, or until Ctrl-C when a person is at a terminal."""
    if seconds is None:
        if not sys.stdin.isatty():
            return
        seconds = float("inf")
    if seconds <= 0:
        return
    print(f"uav-robots: the view stays at {url}" + (" until Ctrl-C" if seconds == float("inf")
                                                     else f" for {seconds:g} s"), flush=True, file=sys.stderr)
    try:
        time.sleep(seconds) if seconds != float("inf") else _forever()
    except KeyboardInterrupt:
        pass


def _forever() -> None:
    while True:
        time.sleep(3600)


class LiveView:
    def __init__(self, port: int, free: np.ndarray, cell_m: float = 1.0) -> None:
        self.state = FleetView()
        self.server = ViewServer(port, free, view=self.state, cell_m=cell_m)
        self.url = self.server.url
        self.pump: Pump | None = None

    def follow(self, observer) -> None:
        self.pump = Pump(observer.since, self.state)

    def hold(self, seconds: float | None, report: dict | None = None) -> None:
        """Serve on after the mission; `report` (report.json, when written) adds what only it knows: the
        robot-mover collisions and near misses of a floor with movers."""
        if self.pump is not None:
            self.pump.close()
        if report:
            self.state.report(report)
        try:
            hold(self.url, seconds)
        finally:
            self.server.close()
