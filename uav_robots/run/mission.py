"""`uav-robots run`: check the arguments, start the mission's processes, record and show it while the UAV
flies, stop everything in order, then sum it up (`outcome.finish`)."""
from __future__ import annotations

import signal
import sys
import time

from protocol.errors import MissionError, UavRobotsError

from .arguments import check_arguments
from .launcher import Launcher
from .outcome import finish
from .spec import from_spec_file, spec_of, write_spec


def start_observer(launcher: Launcher):
    """The recorder: a Zenoh client of the fleet, connected to the UAV's endpoint (the UAV listens)."""
    from ..record.observer import Observer

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
    from ..view.live import LiveView

    try:
        view = LiveView(args.view, free)
    except OSError as exc:
        raise UavRobotsError(f"--view {args.view}: cannot serve there: {exc.strerror or exc}") from None
    print(f"uav-robots: live view at {view.url}", flush=True, file=sys.stderr if args.json else sys.stdout)
    return view


def run(args) -> int:
    from_spec_file(args)
    name, free = check_arguments(args)
    launcher = Launcher(args)
    launcher.floor_shape = free.shape
    launcher.spec = write_spec(launcher.out, spec_of(args))
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
                from ..record.video_ahead import VideoAhead
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
        return finish(args, launcher, uav, code, samples, ahead, view, free, t0)
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)
