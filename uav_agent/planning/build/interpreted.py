"""The same planning pipeline with its numba kernels run by the Python interpreter, in a child process.

On a fresh clone the kernels take tens of seconds to compile; the missions `uav-robots run`
flies (8 robots on 24x18 by default, 50 on the 450x450 warehouse) plan in one to three seconds
when the very same code runs as plain Python. So while `warm.py`'s process compiles, such an
instance is planned by `python -m uav_agent.planning.build.interpreted` with NUMBA_DISABLE_JIT=1
(numba's switch to call the decorated functions as they are written; it is read when numba is
imported, hence a process of its own). Same functions, same seeds, same plans: only slower,
which is why `fits` bounds the instance. The one kernel that visits every cell for every goal,
the breadth-first distance fields, runs as SciPy's compiled Dijkstra instead, with the same
numbers (`mapf/distances._scipy_rows`): interpreted, 50 fields of the 450x450 warehouse took 11 s.

The child reads the instance as JSON on stdin and writes the PlanResult as JSON on stdout;
a planning error becomes exit 2 and its message on stderr, the time limit reached exit 3 (the
compiled kernels may still plan it in time).
"""
from __future__ import annotations

import importlib
import json
import subprocess
import sys
import warnings
from dataclasses import asdict

import numpy as np

from protocol.errors import PlanningError, PlanningTimeout

# Every goal needs a full distance field, about 0.15 us a cell in SciPy (goals x free cells:
# 50 x 126,784 on the 450x450 warehouse, 1 s); the searches, interpreted, grow with the robots
# (50 robots there: 0.6 s, 200: 4 s). Beyond these the compile is the shorter wait.
MAX_FIELD_CELLS = 30_000_000
MAX_ROBOTS = 200
START_MARGIN_S = 30.0      # the child's interpreter and imports, on a loaded machine


def fits(free: np.ndarray, robots: int, goals: int) -> bool:
    """True when interpreting the pipeline on this instance takes a few seconds at most."""
    return robots <= MAX_ROBOTS and goals * int(np.count_nonzero(free)) <= MAX_FIELD_CELLS


def _cells(cells) -> list[tuple[int, int]]:
    return [(int(c[0]), int(c[1])) for c in cells]


class InterpretedPlanner:
    """One interpreted plan in a child process, started ahead: its interpreter and imports (about a
    second) then run while the caller still flies and surveys; `close` ends a child never used."""

    def __init__(self) -> None:
        from protocol.process import die_with_parent
        from .child import child_env

        try:
            self._proc: subprocess.Popen | None = subprocess.Popen(
                [sys.executable, "-m", "uav_agent.planning.build.interpreted"], stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=child_env(NUMBA_DISABLE_JIT="1"),
                preexec_fn=die_with_parent)
        except OSError as exc:
            self._proc, self._error = None, f"the interpreted planner did not start: {exc}"

    def plan(self, free: np.ndarray, starts, goals, **options):
        """`pipeline.plan_mission(free, starts, goals, **options)` in the child (once).

        Raises PlanningError as plan_mission would, and RuntimeError when the child could not
        start, crashed or reached the time limit at the interpreter's pace: then the caller can
        still plan with the compiled kernels."""
        from ..pipeline import PlanResult
        from ..types import Problem
        from ..validator import check

        if self._proc is None:
            raise RuntimeError(self._error)
        request = {"free": ["".join("1" if c else "0" for c in row) for row in np.asarray(free, dtype=bool)],
                   "starts": _cells(starts), "goals": _cells(goals), "options": options}
        timeout = float(options.get("time_limit", 60.0)) + START_MARGIN_S
        try:
            out, err = self._proc.communicate(json.dumps(request), timeout=timeout)
        except (OSError, subprocess.TimeoutExpired) as exc:
            self.close()
            raise RuntimeError(f"the interpreted planner did not finish: {exc}") from None
        why = err.strip().splitlines()[-1] if err.strip() else "planning failed"
        if self._proc.returncode == 2:
            raise PlanningError(why)
        if self._proc.returncode == 3:
            raise RuntimeError(f"interpreted, {why}")
        if self._proc.returncode != 0:
            raise RuntimeError(f"the interpreted planner exited with {self._proc.returncode}: {err.strip()[-500:]}")
        d = json.loads(out)
        result = PlanResult(**{**d, "starts": _cells(d["starts"]), "goals": _cells(d["goals"]),
                               "paths": [_cells(p) for p in d["paths"]]})
        # the child validated its plan; a plan that crossed a process boundary is checked again
        check(Problem(free=np.asarray(free, dtype=bool), starts=result.starts, goals=result.goals,
                      connectivity=result.connectivity), result.paths)
        return result

    def close(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.communicate()


def plan_interpreted(free: np.ndarray, starts, goals, **options):
    """`InterpretedPlanner().plan(...)`, the child started now."""
    planner = InterpretedPlanner()
    try:
        return planner.plan(free, starts, goals, **options)
    finally:
        planner.close()


def main() -> int:
    from ..pipeline import plan_mission

    importlib.import_module("scipy.optimize")   # the assignment's, half a second: before the instance arrives

    request = json.load(sys.stdin)
    free = np.array([[c == "1" for c in row] for row in request["free"]], dtype=bool)
    try:
        # uint64 hashing and random generators wrap around by design, as they do compiled
        with warnings.catch_warnings(), np.errstate(over="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)
            result = plan_mission(free, _cells(request["starts"]), _cells(request["goals"]), **request["options"])
    except PlanningError as exc:
        print(str(exc).replace("\n", " "), file=sys.stderr)
        return 3 if isinstance(exc, PlanningTimeout) else 2
    json.dump(asdict(result), sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
