"""A run's outcome, once every process stopped: report.json (the UAV's with the launcher's additions,
or the launcher's own), the recording and video when kept, the summary lines and the exit code; what
could not be written is named in one line."""
from __future__ import annotations

import json
import shutil
import signal
import sys
import time

from ..common import outputs
from ..record.after_mission import why_failed, write_views
from .launcher import Child, Launcher


def finish(args, launcher: "Launcher", uav: Child | None, code: int, samples: list, ahead, view, free,
           t0: float) -> int:
    """Everything stopped: the report (this run's UAV's with the launcher's additions, or the launcher's
    own), the recording, the video, report.html; each one written whole, or named in one line."""
    from protocol.mapfile import format_rows

    out, quiet = launcher.out, args.quiet or args.json
    report_path = out / outputs.REPORT
    failed: list[str] = []
    report, why = outputs.own_report(out, launcher.fleet)
    uav_code = uav.proc.poll() if uav is not None else None
    uav_ended = "did not start" if uav is None else (f"exited with code {uav_code}" if uav_code is not None
                                                     else "did not end")
    if report is None:
        report = outputs.minimal_report(launcher.fleet, args.robots, f"the UAV {uav_ended} {why}"
                                        + (f"; {launcher.stop_reason}" if launcher.stop_reason else ""))
    report["processes"] = launcher.pids()
    report["exit_codes"] = launcher.exit_codes()
    if launcher.stop_reason:
        report["stopped_by"] = launcher.stop_reason
    report.setdefault("timings", {})["wall_total"] = round(time.perf_counter() - t0, 3)
    wrote = False
    try:
        outputs.write_atomic(report_path, json.dumps(report, indent=1))
        wrote = True
        if report.get("written_by") == "launcher":
            print(f"uav-robots: the UAV {uav_ended} {why}: the launcher wrote {report_path} "
                  "(completed false, outcome aborted)", file=sys.stderr, flush=True)
    except OSError as exc:
        failed.append(f"{outputs.REPORT} ({why_failed(exc)})")
        if why.startswith("with an unreadable"):
            report_path.unlink(missing_ok=True)   # half a report is no report: never left standing
    for c in launcher.children:
        if c.tee is not None and c.tee.log_error is not None:
            failed.append(f"{c.log.relative_to(out)} ({why_failed(c.tee.log_error)})")
    kept = not launcher.temporary or code != 0 or bool(failed)
    t_views = time.perf_counter()
    try:
        if kept and wrote:
            failed += write_views(out, samples, launcher.fleet, format_rows(free), quiet, ahead,
                                  video=launcher.signalled is None, cancel=launcher.hurry)
            if launcher.signalled is not None and not quiet:
                print(f"  no replay.mp4: stopped by {signal.Signals(launcher.signalled).name} "
                      f"(`uav-robots replay {out}` draws it from the recording)", flush=True)
    finally:
        if ahead is not None:
            ahead.discard()     # what `write_views` did not take (a failed run keeps no half video)
    views_s = time.perf_counter() - t_views
    if failed:
        print(f"uav-robots: could not write {', '.join(failed)}", file=sys.stderr, flush=True)
        if code in (0, 3):
            code = 1
    if args.json:
        print(json.dumps({**report, "exit_code": code, "out": str(out) if kept else None},
                         separators=(",", ":")), flush=True)
    elif report.get("written_by") != "launcher":
        # The UAV printed the mission's summary; the launcher adds what only it knows.
        print(f"  whole run: {report['timings']['wall_total']:.2f}s wall (process start-up and shut-down "
              f"included), {len(report['processes']['robots'])} robot process(es)"
              + (f"; then {views_s:.2f}s writing the recording, video and report page" if views_s >= 0.01 else "")
              + ("" if kept else "; outputs were temporary: keep them with --out DIR"), flush=True)
    if code != 0:
        what = "report and logs" if wrote else "logs"
        how = ("completed, but not every output was written" if report.get("completed") is True and failed
               else "did not complete")
        print(f"uav-robots: the mission {how} (exit {code}); {what} in {out if kept else launcher.logs}",
              file=sys.stderr, flush=True)
    if not kept:
        shutil.rmtree(out, ignore_errors=True)
    if view is not None and launcher.signalled is None:
        view.hold(args.view_hold, report)
    elif view is not None:
        view.hold(0)
    return code
