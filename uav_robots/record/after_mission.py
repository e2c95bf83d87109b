"""After a mission: its recording, video and report page written from what the observer heard."""
from __future__ import annotations

import json
import sys
import threading
from pathlib import Path

from ..common import outputs


def write_views(out: Path, samples: list, fleet: str, rows: list[str], quiet: bool, ahead=None,
                video: bool = True, cancel: threading.Event | None = None) -> list[str]:
    """report.html, mission.mcap and, if `video`, replay.mp4 (from the recording, as `uav-robots replay`
    makes it, up to the mission's last tick; the one `ahead` (a VideoAhead) drew while the vehicle
    landed, if the recording draws the same), each whole or not at all. `rows`: the floor, where the
    report has none. Returns what could not be written, each with why."""
    from uav_agent.report import load_report

    from . import recording, replay, report_html

    failed: list[str] = []
    try:
        report = load_report(out)
    except (OSError, ValueError) as exc:   # the UAV's details.json or plan.json (a full disk): without them
        failed.append(f"the report's details ({why_failed(exc)})")
        report = json.loads((out / outputs.REPORT).read_text())
    try:
        report_html.write(out, report)
    except Exception as exc:  # noqa: BLE001 - the report is written; say what is missing
        failed.append(f"{report_html.REPORT_HTML} ({why_failed(exc)})")
    rows = (report.get("truth") or {}).get("rows") or (report.get("plan") or {}).get("map", {}).get("rows") or rows
    cell_m = float((report.get("truth") or {}).get("cell_size_m", 1.0))
    mcap, video_path = out / recording.MCAP, out / replay.VIDEO
    try:
        recording.write_mcap(outputs.partial(mcap), samples, f"uavr/{fleet}", rows, cell_m)
        outputs.partial(mcap).replace(mcap)
    except Exception as exc:  # noqa: BLE001 - as above
        outputs.partial(mcap).unlink(missing_ok=True)
        return failed + [f"{recording.MCAP} ({why_failed(exc)})"] + ([f"{replay.VIDEO} (no recording)"] if video else [])
    if video:
        try:
            rec = recording.read_mcap(mcap)
            last = recording.last_tick(report, rec)
            dropped = recording.bound(rec, last)
            if dropped:
                print(recording.dropped_line(dropped, last), file=sys.stderr, flush=True)
            # The draft drew the movers as heard; the world's record may place some otherwise (a merged tick).
            retraced = recording.take_trace(rec, report)
            if ahead is None or retraced or not ahead.take(samples, rows, video_path, last):
                replay.render(rec, outputs.partial(video_path), cancel=cancel)
                outputs.partial(video_path).replace(video_path)
        except Exception as exc:  # noqa: BLE001 - as above
            outputs.partial(video_path).unlink(missing_ok=True)
            failed.append(f"{replay.VIDEO} ({why_failed(exc)})")
    if not quiet:
        made = [mcap, *([video_path] if video_path.exists() else []), out / report_html.REPORT_HTML]
        print(f"  recording: {made[0]} (Foxglove opens it), " + ", ".join(str(p) for p in made[1:] if p.exists()),
              flush=True)
    return failed


def why_failed(exc: BaseException) -> str:
    """Why an output could not be written, in the few words of a one-line error."""
    from .replay import Cancelled

    if isinstance(exc, Cancelled):
        return "stopped meanwhile"
    return (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)) or type(exc).__name__
