"""The UAV suite's shared steps: what every mission's tests read from a run, and the bounds they hold a UAV to."""
from __future__ import annotations

import re

from conformance.uav_harness import MissionRun, error_lines


RESEND_S = 2.0         # the UAV puts again a plan not acknowledged within this ...
RESEND_SLACK_S = 1.5   # ... give or take this, for the transport and a loaded machine


def exited(run: MissionRun, opts) -> None:
    assert run.code is not None, f"the UAV was still running after {opts.mission_timeout_s:g} s\n{run.tail()}"


def makespan_of(run: MissionRun) -> int:
    return max(len(p.path) for p in run.first_plans().values()) - 1


def no_harness_trouble(run: MissionRun) -> None:
    assert not run.log.harness, f"the suite's own robots failed: {run.log.harness[:3]}"


def ends(run: MissionRun) -> float:
    return run.log.ends[0][0] if run.log.ends else run.exited


def ticks_after(run: MissionRun, k: int) -> list:
    return [t for _, t in run.log.ticks if t.k > k]


def fault(run: MissionRun, kind: str, robot: int | None = None):
    f = run.log.fault(kind, robot)
    assert f is not None, (f"the suite never made its {kind} fault (robot {robot}): the mission went another way "
                           f"({len(run.log.ticks)} ticks)\n{run.tail()}")
    return f


def fails_with_one_line(run: MissionRun, opts, since: float, names: str, within: float) -> None:
    """The UAV ends the mission as failed: exit 1 within `within` s of `since`, no traceback, a stderr line
    matching `names`, MissionEnd(completed=false), its token withdrawn, landed."""
    exited(run, opts)
    assert run.code == 1, f"exit {run.code}, not 1 (a failed or aborted mission)\n{run.tail()}"
    assert run.exited - since <= within, f"the UAV took {run.exited - since:.1f} s to give up (at most {within:g} s)"
    assert "Traceback" not in run.stderr + run.stdout, run.tail()
    lines = error_lines(run.stderr)
    assert any(re.search(names, line) for line in lines), \
        f"no line on stderr names what failed ({names!r}):\n{run.stderr[-1500:]}"
    assert run.log.ends, "no MissionEnd was published"
    assert run.log.ends[-1][1].completed is False, "MissionEnd says completed although the mission failed"
    alive = run.log.uav_alive
    assert alive and not alive[-1][1], "alive/uav is still declared after the UAV exited"
    v = run.vehicle
    if v is not None and v["max_altitude_m"] > 1.0:
        # Safety, not wire format: a leader that gives up must not leave its drone hovering armed.
        assert v["landed_state"] == "ON_GROUND" and not v["armed"], \
            f"after the abort the vehicle is {v['landed_state']}, armed {v['armed']}"
