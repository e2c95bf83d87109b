"""The world's executor of the camera's faults (protocol/faults.py): camera-off:SECONDS+DURATION (a dead
camera: no request is answered, the query just ends, as a camera that no longer speaks leaves it) and
camera-stuck:SECONDS+DURATION (a frozen video pipeline: every request gets the last image rendered
before the window, its pixels, pose, time and seq unchanged).

The windows are on the clock the world stamps its images with (`WorldCamera.camera_clock`, the
`time_s` of each CameraFrame), so a fault lands where the images say it did. `camera_service.py`
asks `state(t)` at each request's shutter; the MAVLink camera component asks through `expose` and
`develop`. Only the camera's answers change: the world renders nothing while the camera is faulty.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, Callable

from protocol.errors import MissionError
from protocol.faults import WORLD, Fault, parse_fault

OFF, STUCK = "off", "stuck"


@dataclass
class CameraFaults:
    windows: tuple[Fault, ...] = ()
    say: Callable[[str], None] = lambda text: print(text, flush=True)
    unanswered: int = 0                      # requests a dead camera left unanswered
    repeated: int = 0                        # requests a frozen one answered with its old image
    _last: tuple[int, Any] | None = None     # (seq, CameraFrame) of the newest image rendered
    _said: set[Fault] = field(default_factory=set)   # the windows whose start has been said
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def state(self, t: float) -> str | None:
        """OFF or STUCK if a window acts at `t` (the camera clock's seconds; a dead camera wins), else None."""
        acting = [f for f in self.windows if f.active_at(t)]
        kind = OFF if any(f.kind == "off" for f in acting) else STUCK if acting else None
        if kind is not None:
            fault = next(f for f in acting if f.kind == kind)
            with self._lock:
                new = fault not in self._said
                self._said.add(fault)
            if new:   # one line a window: the world's log shows the fault landed, and when
                self.say(f"world: fault {fault} acts at t={t:.1f} s: the camera "
                         + ("answers nothing" if kind == OFF else "repeats its last image") + f" until "
                         f"t={fault.seconds + fault.duration} s")
        return kind

    def count(self, kind: str) -> None:
        """A request the fault changed the answer of: left unanswered (OFF) or given the old image (STUCK)."""
        with self._lock:
            if kind == OFF:
                self.unanswered += 1
            else:
                self.repeated += 1

    def remember(self, seq: int, frame: Any) -> None:
        """An image rendered (in any order the render pool finishes them): the newest is kept to repeat."""
        with self._lock:
            if self._last is None or seq >= self._last[0]:
                self._last = (seq, frame)

    def frozen(self) -> Any:
        """The image a frozen camera repeats, None if it never rendered one (then it has nothing to show)."""
        with self._lock:
            return None if self._last is None else self._last[1]

    def summary(self) -> str:
        return (f"camera faults: {self.unanswered} request(s) unanswered, {self.repeated} answered with a "
                f"frozen image")

    # --- the MAVLink camera component's shutter and development -------------------------

    def expose(self, expose: Callable[[], tuple]) -> Callable[[], tuple]:
        """`expose` for the component: a dead camera takes no image (the component reports it failed)."""
        def shutter() -> tuple:
            shot = expose()
            if self.state(shot[5]) == OFF:
                self.count(OFF)
                raise MissionError("the camera is off (an injected fault)")
            return shot
        return shutter

    def develop(self, develop: Callable[[tuple], Any]) -> Callable[[tuple], Any]:
        """`develop` for the component: a frozen camera gives its old image for a shot in its window."""
        def film(shot: tuple) -> Any:
            if self.state(shot[5]) == STUCK:
                old = self.frozen()
                if old is None:
                    raise MissionError("the camera is frozen before its first image (an injected fault)")
                self.count(STUCK)
                return old
            frame = develop(shot)
            self.remember(shot[6], frame)
            return frame
        return film


def camera_faults(specs: list[str], say: Callable[[str], None] | None = None) -> CameraFaults | None:
    """The camera's faults among the world's `specs`; None if there are none (the camera as it is)."""
    windows = tuple(f for f in (parse_fault(s, WORLD) for s in specs) if f.kind in (OFF, STUCK))
    return (CameraFaults(windows) if say is None else CameraFaults(windows, say)) if windows else None
