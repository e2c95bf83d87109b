"""The end of a mission: MissionEnd said once, the vehicle landed (on an abort, off the floor, or
left to the autopilot that took it), and a stop from outside that still lands and reports."""
from __future__ import annotations

import signal
import time

from protocol.errors import MissionError
from protocol.messages import MissionEnd
from protocol.codec import encode

from . import score
from .context import MissionContext

ABORT_LAND_TIMEOUT_S = 60.0
STOP_LAND_TIMEOUT_S = 10.0  # stopped by a signal or left by the world: the landing is bounded by this


def end(ctx: MissionContext, completed: bool, reason: str) -> None:
    if ctx.ended:
        return
    ctx.ended = True
    ctx.previewer.close()   # the mission's last images reach observers before its end
    ctx.transport.put(ctx.keys.mission_end, encode(MissionEnd(completed=completed, reason=reason,
                                                              seq=ctx.next_seq())))


def land(ctx: MissionContext) -> None:
    ctx.status("land", message="landing over MAVLink")
    ctx.flight.land()
    ctx.pose_feed.flying(False)
    ctx.uav["landed"] = True
    ctx.clock.lap("land")


def abort_course(ctx: MissionContext) -> str:
    """What becomes of the vehicle after an abort, as `abort_landing` will do it."""
    if ctx.flight is None or not ctx.uav["armed"] or ctx.uav["landed"]:
        return "the vehicle stays on the ground"
    if ctx.watch is not None and ctx.watch.failsafe:
        return "the autopilot brings the vehicle down"
    return "landing the vehicle"


def aborted(ctx: MissionContext, exc: BaseException) -> None:
    """A failed mission must not leave the drone hovering armed: land it, then report the failure."""
    why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    ctx.event("abort", [], why, "ended the mission; " + abort_course(ctx))
    try:
        end(ctx, False, why)   # the robots and observers hear why, not just "aborted"
    except Exception:  # noqa: BLE001 - the session may be what failed
        pass
    abort_landing(ctx)
    score.abort_report(ctx, str(exc))


def stopped(ctx: MissionContext, exc: BaseException) -> None:
    """Stopped from outside: the report first (a second signal must not lose it), then a bounded
    landing, then the report again with the landing's outcome. Further signals wait meanwhile:
    the stop is bounded by STOP_LAND_TIMEOUT_S and the record's query."""
    why = "stopped by SIGTERM" if isinstance(exc, SystemExit) else "interrupted (SIGINT)"
    held = _hold_signals()
    try:
        ctx.event("abort", [], why, "ended the mission, wrote the report; " + abort_course(ctx))
        try:
            end(ctx, False, why)
        except Exception:  # noqa: BLE001 - the session may already be gone
            pass
        score.abort_report(ctx, why, record_timeout_s=2.0)
        if ctx.flight is not None and ctx.uav["armed"] and not ctx.uav["landed"]:
            abort_landing(ctx, STOP_LAND_TIMEOUT_S)
            score.abort_report(ctx, why, record_timeout_s=2.0)
    finally:
        _restore_signals(held)


def abort_landing(ctx: MissionContext, timeout_s: float = ABORT_LAND_TIMEOUT_S) -> None:
    if ctx.watch is not None:
        ctx.watch.expect_airborne(False)
    if ctx.flight is None or not ctx.uav["armed"] or ctx.uav["landed"]:
        return
    try:
        end(ctx, False, "mission aborted")
        if ctx.watch is not None and ctx.watch.failsafe:
            _follow_down(ctx, timeout_s)
            return
        spot = _abort_spot(ctx)
        if spot is not None:
            ctx.progress.phase("abort", f"flying off the floor to land at N {spot[0]:.1f} E {spot[1]:.1f}")
            try:
                ctx.flight.goto(*spot, timeout_s=timeout_s / 2)
            except MissionError as exc:   # land where it is rather than not at all
                ctx.progress.phase("abort", f"could not reach the landing spot: {exc}")
        ctx.progress.phase("abort", "landing the vehicle")
        ctx.flight.land(timeout_s=timeout_s)
        if ctx.pose_feed is not None:
            ctx.pose_feed.flying(False)
        ctx.uav["landed"] = True
    except Exception as exc:  # noqa: BLE001 - the link may be the thing that failed
        ctx.progress.phase("abort", f"could not land: {exc}")


def _follow_down(ctx: MissionContext, timeout_s: float) -> None:
    """The autopilot took the vehicle (a failsafe's RTL or LAND, a pilot, a disarm): no command of the
    mission's goes over its decision, not even a landing; the mission only watches it come down."""
    taken = ctx.watch.taken_by
    ctx.uav["left_to_autopilot"] = taken
    ctx.progress.phase("abort", f"the autopilot has the vehicle ({taken}): not commanding it, watching it land")
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if ctx.flight.landed:
                ctx.uav["landed"] = True
                break
        except MissionError:
            break
        time.sleep(0.2)
    if ctx.pose_feed is not None and ctx.uav["landed"]:
        ctx.pose_feed.flying(False)


def _abort_spot(ctx: MissionContext) -> tuple[float, float, float] | None:
    """Where an abort lands (`landing.abort_spot`); None before the floor is known or on the ground."""
    from ..landing import abort_spot

    info = ctx.info
    if info is None or not ctx.flight.in_air:
        return None
    n, e, d = ctx.flight.position_ned()
    return abort_spot(n, e, -d, info.width, info.height, info.cell_size_m)


def _hold_signals() -> list:
    """SIGTERM and SIGINT ignored for a while (only the main thread may say so; elsewhere nothing)."""
    held = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        try:
            held.append((sig, signal.signal(sig, signal.SIG_IGN)))
        except ValueError:
            pass
    return held


def _restore_signals(held: list) -> None:
    for sig, handler in held:
        signal.signal(sig, handler)


def close(ctx: MissionContext) -> None:
    """Whatever the mission opened, closed; MissionEnd said if nothing said it yet."""
    if not ctx.ended:
        try:
            end(ctx, False, "mission aborted")
        except Exception:  # noqa: BLE001 - the session may already be gone
            pass
    for part in (ctx.watch, ctx.pose_feed, ctx.camera, ctx.flight):
        if part is not None:
            part.close()
    ctx.fleet.close()
    if ctx.compile.interpreter is not None:
        ctx.compile.interpreter.close()
    ctx.transport.close()
    ctx.progress.close()
