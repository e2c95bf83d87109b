"""A run's output directory (`--out`): what a run writes there, an earlier run's outputs cleared before a
new run starts, files written whole or not at all, and the report the launcher writes when the UAV wrote none.

Nothing an earlier run left may stand as the new run's: the launcher removes the known outputs and logs
of an earlier run before it starts a process (and says so), and amends a report.json only if this run's
UAV wrote it (its `fleet` is this run's fleet name).
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from protocol.errors import UavRobotsError

REPORT = "report.json"
LOGS = "logs"
# Every file a run writes into its directory: the UAV's (report, details, plan, images) and the
# launcher's (recording, video and its draft, report page).
OUTPUTS = (REPORT, "run.json", "details.json", "plan.json", "overhead.png", "paths.png", "replay.gif",
           "mission.mcap", "replay.mp4", ".replay-draft.mp4", "report.html")
_PARTIAL = ".partial-"    # a file being written (write_atomic): never an output


def clear_earlier(out: Path) -> list[str]:
    """Remove an earlier run's outputs and logs from `out`; returns what was removed (empty for a new
    directory). A file that cannot be removed is bad input: one line, before any process starts."""
    found = [out / name for name in OUTPUTS] + sorted(out.glob(f"{_PARTIAL}*"))
    logs = sorted((out / LOGS).glob("*.log")) if (out / LOGS).is_dir() else []
    removed = []
    for path in found + logs:
        if not (path.is_file() or path.is_symlink()):
            continue
        try:
            path.unlink()
        except OSError as exc:
            raise UavRobotsError(f"--out {out}: cannot remove the earlier run's {path.relative_to(out)}: "
                                 f"{exc.strerror or exc}") from None
        if path.parent == out:
            removed.append(path.name)
    if logs:
        removed.append(f"{LOGS}/ ({len(logs)} logs)")
    return removed


def partial(path: Path) -> Path:
    """Where `path` is written before it is renamed into place (same directory, same suffix: OpenCV
    picks a video's container by it)."""
    return path.with_name(f"{_PARTIAL}{path.name}")


def write_atomic(path: Path, text: str) -> None:
    """`text` into `path` whole or not at all: a temporary file beside it, then a rename. A full disk
    leaves no half-written file (an OSError says what failed)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{_PARTIAL}{path.name}.")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def own_report(out: Path, fleet: str) -> tuple[dict[str, Any] | None, str]:
    """(report.json as this run's UAV wrote it, or None; why not). A report of another fleet is
    another run's, never this one's."""
    try:
        report = json.loads((out / REPORT).read_text())
    except FileNotFoundError:
        return None, "without a report"
    except (OSError, ValueError) as exc:
        return None, f"with an unreadable report.json ({exc})"
    if not isinstance(report, dict) or report.get("fleet") != fleet:
        other = report.get("fleet") if isinstance(report, dict) else None
        return None, f"without a report of its own (report.json there is fleet {other!r}'s, not {fleet!r}'s)"
    return report, ""


def minimal_report(fleet: str, robots: int, reason: str) -> dict[str, Any]:
    """What the launcher knows of a mission whose UAV wrote no report: that it did not complete, and why."""
    return {"format": "uav-robots-report/1", "completed": False, "outcome": "aborted", "reason": reason,
            "robots": robots, "fleet": fleet, "written_by": "launcher", "done": [], "verified": {},
            "events": [], "timings": {}}
