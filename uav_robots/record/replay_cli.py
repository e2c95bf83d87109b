"""`uav-robots replay DIR`: replay.mp4 rendered again from DIR/mission.mcap."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from protocol.errors import MissionError, UavRobotsError


def add_replay_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("replay", help="render a recorded mission (DIR/mission.mcap) again",
                              description="Read DIR/mission.mcap (written by `uav-robots run --out DIR`) and "
                                          "write DIR/replay.mp4 from it; with --view, also serve the recorded "
                                          "mission in the live view's page, with a time slider.")
    p.add_argument("dir", help="a run's --out directory")
    from ..view.arguments import add_view_arguments

    add_view_arguments(p)
    p.set_defaults(func=replay_command)
    return p


def replay_command(args: argparse.Namespace) -> int:
    from .recording import MCAP, bound, dropped_line, last_tick, read_mcap, take_trace
    from ..common.outputs import partial
    from .replay import VIDEO, render

    directory = Path(args.dir)
    if not (directory / MCAP).is_file():
        raise UavRobotsError(f"{args.dir}: no {MCAP} there (write one with `uav-robots run --out {args.dir}`)")
    try:
        rec = read_mcap(directory / MCAP)
    except Exception as exc:  # noqa: BLE001 - a damaged or foreign file is bad input
        raise UavRobotsError(f"{directory / MCAP}: not a readable uav-robots recording: {exc}") from None
    report = _report(directory)
    last = last_tick(report, rec)
    dropped = bound(rec, last)
    if dropped:
        print(dropped_line(dropped, last), file=sys.stderr, flush=True)
    take_trace(rec, report)    # the movers of every tick, as the world recorded them, where it did
    draft = partial(directory / VIDEO)    # an earlier replay.mp4 stays until the new one is whole
    try:
        frames, w, h = render(rec, draft)
        draft.replace(directory / VIDEO)
    except OSError as exc:
        draft.unlink(missing_ok=True)
        raise MissionError(f"could not write {directory / VIDEO}: {exc.strerror or exc}") from None
    movers = len({m for at in rec.movers.values() for m in at})
    print(f"{directory / VIDEO}: {frames} frames, {w}x{h} px, ticks 0-{rec.ticks}, {len(rec.cells)} robots"
          + (f", {movers} movers" if movers else ""), flush=True)
    if args.view is not None:
        from .replay import timeline
        from ..view.live import hold
        from ..view.server import ViewServer

        try:
            server = ViewServer(args.view, rec.free, timeline=timeline(rec, report))
        except OSError as exc:
            raise UavRobotsError(f"--view {args.view}: cannot serve there: {exc.strerror or exc}") from None
        print(f"uav-robots: recorded mission at {server.url}", flush=True)
        try:
            hold(server.url, args.view_hold)
        finally:
            server.close()
    return 0


def _report(directory: Path) -> dict[str, Any] | None:
    """The run's report with its details and plan, if it has a readable one: what bounds the replay."""
    from uav_agent.report import load_report

    try:
        return load_report(directory)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
