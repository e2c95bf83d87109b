"""A mission's record on disk: report.json for people, details.json and plan.json for programs,
the pictures beside them, and the exit code and summary the command ends with. The UAV writes it;
the launcher, replay and the benchmarks read it."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

from protocol.messages import CameraFrame

EXIT_COMPLETED, EXIT_ABORTED, EXIT_DEGRADED = 0, 1, 3


def registration_summary(frames) -> dict[str, Any]:
    """How the survey's images were placed on the floor: by landmarks or by the pose estimate alone."""
    errors = [f.reprojection_px for f in frames if f.source == "landmarks" and f.reprojection_px is not None]
    return {"by_landmarks": sum(f.source == "landmarks" for f in frames),
            "by_estimate": sum(f.source != "landmarks" for f in frames),
            "reprojection_px_max": round(max(errors), 3) if errors else None,
            "reprojection_px_median": round(sorted(errors)[len(errors) // 2], 3) if errors else None}


def exit_code(report: dict[str, Any]) -> int:
    """0 every robot verified on its goal; 3 finished with a degraded fleet; 1 failed or aborted."""
    if report.get("completed"):
        return EXIT_COMPLETED
    return EXIT_DEGRADED if report.get("outcome") == "degraded" else EXIT_ABORTED


DETAILS = "details.json"   # the per-tick and per-cell data, beside the compact report.json
PLAN = "plan.json"         # the first plan, in the plan file format (uav-robots plan --out)
GIF_MAX_SIDE = 64          # cells: beyond, a robot is a pixel or two in a GIF


def split_report(report: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any] | None]:
    """(report.json, details.json, plan.json): what a person reads apart from the bulk a program reads."""
    compact = {k: v for k, v in report.items() if k not in ("executed", "refused")}
    plan = report.get("plan")
    if plan is not None:
        compact["plan"] = {**{k: v for k, v in plan.items() if k not in ("map", "robots")}, "file": PLAN,
                           "robots": [{"id": r["id"], "start": r["start"], "goal": r["goal"]} for r in plan["robots"]]}
    rows = {}
    for part in ("perceived", "truth"):
        if report.get(part):
            compact[part] = {k: v for k, v in report[part].items() if k != "rows"}
            rows[part] = report[part].get("rows")
    if rows.get("perceived") is not None and rows.get("truth") is not None:
        compact["perceived"]["map_matches_truth"] = rows["perceived"] == rows["truth"]
    details = {"format": "uav-robots-details/1", "executed": report.get("executed", {}),
               "refused": report.get("refused", []), "rows": rows}
    compact["details"] = DETAILS
    return compact, details, plan


def _write_whole(path: Path, data: str | bytes) -> None:
    """The file whole or not at all (a full disk must not leave half a report standing): written beside,
    then renamed over (`.partial-*` left behind by a kill is removed by the launcher)."""
    tmp = path.with_name(f".partial-{path.name}")
    try:
        (tmp.write_bytes if isinstance(data, bytes) else tmp.write_text)(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_report(out: Path, report: dict[str, Any]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    compact, details, plan = split_report(report)
    _write_whole(out / "report.json", json.dumps(compact, indent=1))
    _write_whole(out / DETAILS, json.dumps(details, separators=(",", ":")))
    if plan is not None:
        _write_whole(out / PLAN, json.dumps(plan, separators=(",", ":")))


def load_report(out: Path) -> dict[str, Any]:
    """report.json with details.json and plan.json put back in: the whole record of a mission."""
    report = json.loads((out / "report.json").read_text())
    details = json.loads((out / DETAILS).read_text()) if (out / DETAILS).exists() else {}
    report["executed"] = details.get("executed", {})
    report["refused"] = details.get("refused", [])
    for part, rows in details.get("rows", {}).items():
        if report.get(part) is not None:
            report[part]["rows"] = rows
    if (out / PLAN).exists():
        report["plan"] = json.loads((out / PLAN).read_text())
    return report


def write_outputs(out: Path, report: dict[str, Any], frames: list[CameraFrame], free, result,
                  ids: list[int]) -> None:
    """report.json (+ details.json, plan.json), overhead.png (a captured image), paths.png and replay.gif."""
    from . import visualize

    write_report(out, report)   # first: the pictures are worth less than the record
    executed = {int(k): [tuple(c) for c in v] for k, v in report["executed"].items()}
    goals = {rid: tuple(g) for rid, g in zip(ids, result.goals)}
    pictures = [("overhead.png", lambda: _write_whole(out / "overhead.png", frames[len(frames) // 2].png)
                 if frames else None),
                ("paths.png", lambda: visualize.write_png(out / "paths.png",
                                                          visualize.draw_paths(free, result.paths, result.goals))),
                # larger floors: replay.mp4 (uav-robots run --out) is readable
                ("replay.gif", lambda: visualize.replay_gif(out / "replay.gif", free, executed, goals)
                 if max(free.shape) <= GIF_MAX_SIDE else None)]
    for name, write in pictures:
        try:
            write()
        except OSError as exc:
            print(f"uav: could not write {out / name}: {exc.strerror or exc}", file=sys.stderr, flush=True)


def summary(report: dict[str, Any], out: Path | None) -> str:
    """The few lines a person reads at the end of a mission."""
    t = report["timings"]
    verified = report.get("verified", {})
    outcome = report.get("outcome", "completed" if report["completed"] else "failed").upper()
    lines = [
        f"mission {outcome}: {sum(verified.values())}/{report['robots']} robots verified on their goals by the "
        f"camera in {report['ticks']} ticks, collisions {report['collisions']}"
        + (f" (safety stops {report['safety_stops']}: robots stopped by one that failed or slipped unseen)"
           if report.get("safety_stops") else ""),
    ]
    if report.get("movers"):
        lines.append(f"  movers: {report['movers']} on the floor, {report.get('mover_collisions', 0)} robot-mover "
                     f"collisions, {report.get('near_misses', 0)} near misses (a robot within one cell of one)")
    if report.get("plan"):
        m = report["plan"]["metrics"]
        lines.append(f"  plan: {report['plan'].get('planner', '?')}, sum of costs {m['sum_of_costs']} "
                     f"(lower bound {m.get('lower_bound', '?')}), makespan {m['makespan']}")
    events = report.get("events", [])
    if events or report.get("replans"):
        lines.append(f"  events: {len(events)}, replans {report.get('replans', 0)}, out of the plan "
                     f"{report.get('lost', [])}, unserved goals {report.get('unserved_goals', [])}")
        for e in events[:8]:
            lines.append(f"    tick {e['tick']}: {e['kind']} {e['robots']} {e['what']}"
                         + (f" -> {e['action']}" if e["action"] else ""))
        if len(events) > 8:
            lines.append(f"    ... {len(events) - 8} more in report.json")
    if report.get("outcome") not in (None, "completed"):
        lines.append(f"  reason: {report.get('reason', '')}")
    lines += [
        f"  uav: armed {report['uav']['armed']}, max altitude {report['uav']['max_altitude_m']} m, "
        f"landed {report['uav']['landed']}",
        "  time: " + ", ".join(f"{k} {v:.2f}s" for k, v in t.items()),
    ]
    if out:
        gif = ", replay.gif" if (out / "replay.gif").exists() else ""
        lines.append(f"  outputs: {out}/report.json, details.json, plan.json, overhead.png, paths.png{gif}")
    return "\n".join(lines)
