"""The planning kernels built ahead of time (uav_agent/planning/build/aot.py, jit.py): a real build
with numba's pycc and the C compiler into a cache directory of the test's own, then fresh
processes that plan with it, without numba, the very plans numba's JIT gives."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from uav_agent.planning.build.aot import missing_tools
from uav_agent.planning.compile.prebuilt import kind

# The module's fixture builds the planners ahead of time (about a minute): out of the developer lane.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[3]

needs_compiler = pytest.mark.skipif(missing_tools() is not None,
                                    reason=f"the ahead-of-time build needs {missing_tools()}")


class _Pair(NamedTuple):
    a: np.ndarray
    n: int


def test_kind_tells_apart_what_a_compiled_signature_does():
    a = np.zeros((3, 4), dtype=np.int32)
    assert kind(a) == ("<i4", 2, "C", True)
    assert kind(np.asfortranarray(a)) == ("<i4", 2, "F", True)
    assert kind(a[:, ::2]) == ("<i4", 2, "A", True)
    ro = a.copy()
    ro.flags.writeable = False
    assert kind(ro) == ("<i4", 2, "C", False)
    assert kind(a.astype(np.uint16)) != kind(a)
    # bool before int: True is an int to Python, a boolean to numba
    assert (kind(True), kind(1), kind(1.0), kind(np.int32(1))) == ("b", "i", "f", "<i4")
    # numba types these scalars as the Python values: the same compiled function takes both
    assert (kind(np.bool_(True)), kind(np.int64(1)), kind(np.float64(1))) == ("b", "i", "f")
    assert kind(_Pair(a, 3)) == ("_Pair", ("<i4", 2, "C", True), "i")


def _env(cache: Path | None, kernels: str | None = None) -> dict[str, str]:
    """The environment of a child process: `cache` as NUMBA_CACHE_DIR (None: numba's default)."""
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "UAV_ROBOTS_KERNELS")}
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    env["PYTHONPATH"] = str(ROOT)
    if kernels:
        env["UAV_ROBOTS_KERNELS"] = kernels
    return env


# Plans with every planner on a small warehouse in both connectivities, refines one plan (its
# rounds depend on the clock: validated, not compared), and says which kernels the process used
# and whether it imported numba. The kernels are loaded (or compiled) before the first plan.
_PLANS = r"""
import json, sys
from scenarios import maps
from uav_agent.planning.build.warm import warm_up
from uav_agent.planning.pipeline import plan_mission
from uav_agent.planning.compile import jit
warm_up()    # a JIT compile inside a plan's clock would cut LaCAM's time-bounded guided search short
free = maps.warehouse(4, 6)
out = {}
for robots in (30, 200):         # LaCAM's guide paths alone, then its search (too dense for guides)
    place = maps.place(free, robots, 3)
    for conn in (4, 8):
        for planner in ("lacam", "pibt", "prioritized", "paper-astar", "paper-prm"):
            r = plan_mission(free, place.starts, place.goals, planner=planner, connectivity=conn, seed=1)
            out[f"{robots}/{planner}/{conn}"] = [r.metrics, r.paths]
        plan_mission(free, place.starts, place.goals, planner="pibt", connectivity=conn, refine_s=0.2, seed=1)
print(json.dumps({"mode": jit.MODE, "numba": "numba" in sys.modules, "plans": out}))
"""

# A kernel called with an argument layout the build never saw: numba's JIT takes that call.
_FALLBACK = r"""
import json, sys
import numpy as np
from uav_agent.planning.compile import jit
from uav_agent.planning.mapf.distances import _bfs, grid_graph

free = np.ones((5, 7), dtype=bool); free[2, 1:6] = False
g = grid_graph(free, 4)
def field(dtype):
    base = g.base.astype(dtype)
    dist = np.empty_like(base)
    _bfs(base, 9, False, int(g.padded[0]), dist, np.empty(g.n, dtype=np.int32), -1, -2, 1000)
    return dist
c = field(np.int32)
f = field(np.int64)     # no planner calls it so
print(json.dumps({"mode": jit.MODE, "same": bool((c == f).all()), "numba": "numba" in sys.modules}))
"""


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    cache = tmp_path_factory.mktemp("aot-cache")
    done = subprocess.run([sys.executable, "-m", "uav_robots", "build"], cwd=ROOT, env=_env(cache),
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "built ahead of time" in done.stdout
    return cache


def _run(code: str, env: dict[str, str]) -> tuple[dict, str]:
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stderr


@pytest.mark.slow
@needs_compiler
@pytest.mark.process
def test_a_build_plans_without_numba_and_as_the_jit_does(build):
    again = subprocess.run([sys.executable, "-m", "uav_robots", "build"], cwd=ROOT, env=_env(build),
                           capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and "built already" in again.stdout
    aot, err = _run(_PLANS, _env(build))
    assert aot["mode"] == "aot" and not aot["numba"], err
    assert "no ahead-of-time build" not in err       # every call the planners make was built
    jit_plans, _ = _run(_PLANS, _env(None, kernels="jit"))    # numba's cache, which the suite shares
    assert jit_plans["mode"] == "jit"
    assert aot["plans"] == jit_plans["plans"]


@needs_compiler
@pytest.mark.process
def test_an_argument_the_build_never_saw_falls_back_to_numba(build):
    out, err = _run(_FALLBACK, _env(build))
    assert out == {"mode": "aot", "same": True, "numba": True}
    assert "_bfs has no ahead-of-time build for these argument types" in err


@needs_compiler
@pytest.mark.process
def test_a_changed_source_is_not_loaded_from_an_old_build(build):
    # another build's name (an edit of any planning source): the process keeps the JIT
    manifest = next(build.glob("*/aot/kernels_*.json"))
    moved = manifest.with_name("kernels_0000000000000000.json")
    manifest.rename(moved)
    try:
        out, _ = _run("import json; from uav_agent.planning.compile import jit; print(json.dumps({'mode': jit.MODE}))",
                      _env(build))
        assert out["mode"] == "jit"
    finally:
        moved.rename(manifest)


@pytest.mark.process
def test_a_machine_without_a_compiler_is_told_in_one_line(tmp_path):
    env = {**_env(tmp_path), "CC": str(tmp_path / "no-such-cc")}
    done = subprocess.run([sys.executable, "-m", "uav_robots", "build"], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip() == ("error: the ahead-of-time build needs a C compiler (`cc`); "
                                   "the planners keep numba's JIT")
    assert not list(tmp_path.glob("*/aot/kernels_*"))


@needs_compiler
@pytest.mark.process
def test_numbas_own_switch_runs_the_kernels_interpreted_beside_a_build(build):
    # build/interpreted.py's child asks for plain Python with NUMBA_DISABLE_JIT=1: a build there would
    # plan in milliseconds what a fresh clone's first run plans interpreted
    env = {**_env(build), "NUMBA_DISABLE_JIT": "1"}
    out, _ = _run("import json, sys; from uav_agent.planning.compile import jit; "
                  "print(json.dumps({'mode': jit.MODE, 'interpreted': jit.INTERPRETED}))", env)
    assert out == {"mode": "interpreted", "interpreted": True}
