"""A fresh clone's first run: the kernels compile in a process of their own under a lock, and a
small instance is planned meanwhile by the same planners interpreted."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from protocol.errors import PlanningError
from scenarios.maps import NAMED, place, resolve_map, warehouse
from uav_agent.planning.build import warm
from uav_agent.planning.compile import cache, lock, stale
from uav_agent.planning.build.interpreted import InterpretedPlanner, fits, plan_interpreted
from uav_agent.planning.pipeline import plan_mission

ROOT = Path(__file__).resolve().parents[3]
MAPF = cache.PLANNING_DIR / "mapf"      # where most kernels live, LaCAM's search among them


def corridor():
    """Head-on robots in a 1-wide corridor with one side pocket: too dense for the guide
    paths, so LaCAM's search and PIBT plan it."""
    free = np.zeros((2, 7), dtype=bool)
    free[0, :] = True
    free[1, 3] = True
    return free, [(0, 0), (6, 0)], [(6, 0), (0, 0)]


def instances():
    out = []
    for seed in (0, 1, 2):
        free = warehouse(**NAMED["warehouse-small"])
        pl = place(free, 8, seed)
        out.append((f"warehouse-small-8-{seed}", free, pl.starts, pl.goals, 4, seed))
    _, free = resolve_map("random:width=20,height=20,density=0.2", 5)
    pl = place(free, 12, 5)
    out.append(("random-20-12", free, pl.starts, pl.goals, 8, 5))
    free, starts, goals = corridor()
    out.append(("corridor", free, starts, goals, 4, 0))
    _, free = resolve_map("warehouse-450", 0)     # `uav-robots run --map warehouse-450`'s size
    pl = place(free, 50, 0)
    out.append(("warehouse-450-50", free, pl.starts, pl.goals, 4, 0))
    return out


@pytest.fixture(scope="module")
def compiled():
    """The kernels compiled before any plan is timed, as `uav-robots plan` does: on a fresh clone a
    compile inside the time limit cuts the guide paths short, and the plan differs."""
    from uav_agent.planning.build.warm import warm_up

    with lock.kernel_lock():
        if not warm.is_warm():
            warm_up("lacam", 4)


@pytest.mark.slow
@pytest.mark.parametrize("name,free,starts,goals,connectivity,seed", instances(), ids=lambda v: v if isinstance(v, str) else "")
@pytest.mark.process
def test_interpreted_plans_are_the_compiled_plans(compiled, name, free, starts, goals, connectivity, seed):
    kw = dict(planner="lacam", assign="optimal", connectivity=connectivity, time_limit=60.0, fallback=True, seed=seed)
    compiled = plan_mission(free, starts, goals, **kw)
    interpreted = plan_interpreted(free, starts, goals, **kw)
    assert fits(free, len(starts), len(goals))
    assert interpreted.paths == compiled.paths
    assert interpreted.goals == compiled.goals and interpreted.assignment == compiled.assignment
    assert interpreted.metrics == compiled.metrics and interpreted.planner == compiled.planner


@pytest.mark.process
def test_interpreted_planning_error_is_one_line():
    free = np.ones((3, 5), dtype=bool)
    free[:, 2] = False       # the goal is behind a wall
    kw = dict(planner="lacam", assign="none", connectivity=4, time_limit=10.0, fallback=True, seed=0)
    with pytest.raises(PlanningError) as compiled:
        plan_mission(free, [(0, 0)], [(4, 0)], **kw)
    with pytest.raises(PlanningError) as interpreted:
        plan_interpreted(free, [(0, 0)], [(4, 0)], **kw)
    assert str(interpreted.value) == str(compiled.value) and "cannot reach" in str(compiled.value)


@pytest.mark.process
def test_the_time_limit_reached_interpreted_is_left_to_the_compiled_kernels():
    """Not a planning error: the compiled kernels may well plan it in time (the mission and
    `uav-robots plan` then wait for them)."""
    _, free = resolve_map("warehouse-450", 0)
    pl = place(free, 50, 0)
    with pytest.raises(RuntimeError, match="time limit of 0.2 s reached"):
        plan_interpreted(free, pl.starts, pl.goals, planner="lacam", assign="optimal", connectivity=4,
                         time_limit=0.2, fallback=True, seed=0)


@pytest.mark.process
def test_a_planner_started_ahead_plans_what_a_new_one_plans_and_an_unused_one_ends():
    """The mission starts the interpreted child while the vehicle takes off: the same plan when the
    instance comes, and no process left behind when none does."""
    free, starts, goals = corridor()
    kw = dict(planner="lacam", assign="none", connectivity=4, time_limit=30.0, fallback=True, seed=0)
    ahead = InterpretedPlanner()
    try:
        assert ahead.plan(free, starts, goals, **kw).paths == plan_interpreted(free, starts, goals, **kw).paths
    finally:
        ahead.close()
    unused = InterpretedPlanner()
    unused.close()
    assert unused._proc.returncode is not None


def test_only_instances_that_plan_in_seconds_are_interpreted():
    small = warehouse(**NAMED["warehouse-small"])
    assert fits(small, 8, 8)
    _, big = resolve_map("warehouse-450", 0)
    assert fits(big, 50, 50)
    assert not fits(big, 300, 300)       # 300 distance fields and searches: the compile is sooner
    assert not fits(small, 250, 250)


def _numba_cache_path(cache_dir: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    if cache_dir:
        env["NUMBA_CACHE_DIR"] = cache_dir
    code = "from uav_agent.planning.mapf.lacam import _search; print(_search._cache._cache_path)"
    env["UAV_ROBOTS_KERNELS"] = "jit"     # numba's dispatchers, even beside an ahead-of-time build
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env={**env, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.process
def test_cache_dir_is_where_numba_caches(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert cache.cache_dir(MAPF) == Path(_numba_cache_path(str(tmp_path)))
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert cache.cache_dir(MAPF) == Path(_numba_cache_path(None))


@pytest.mark.process
def test_a_changed_source_empties_numba_cache_once(tmp_path, monkeypatch):
    """numba checks a cached kernel against its own file only; the stamp of every planning source
    beside the cache empties it when any of them changed (an edit of a helper in another file)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    d, home = cache.cache_dir(MAPF), cache.cache_dir()
    d.mkdir(parents=True)
    home.mkdir(parents=True)
    old = [d / "lacam._search-277.py311.nbi", d / "lacam._search-277.py311.1.nbc"]
    for f in old:
        f.write_bytes(b"compiled against other sources")
    (home / "sources.stamp").write_text("kernels_0000000000000000")
    stale.drop_stale_cache()
    assert not any(f.exists() for f in old)
    assert (home / "sources.stamp").read_text() == cache.build_name()
    # the same sources: what was cached since stays
    kept = d / "pibt._run-315.py311.nbi"
    kept.write_bytes(b"compiled against these sources")
    stale.drop_stale_cache()
    assert kept.exists()
    # and a JIT process does it before loading any kernel: a real kernel compiles into the fresh cache
    code = ("from uav_agent.planning.mapf.distances import distance_field; import numpy as np; "
            "print(distance_field(np.ones((3, 4), dtype=bool), (0, 0), 4)[2, 3])")
    (home / "sources.stamp").write_text("kernels_0000000000000000")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "UAV_ROBOTS_KERNELS": "jit", "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "5", done.stderr[-1000:]
    assert not kept.exists() and (home / "sources.stamp").read_text() == cache.build_name()
    assert list(d.glob("distances.*.nbi"))


def test_every_module_with_kernels_names_the_build():
    """A build (and numba's cache stamp) is named after every module that defines kernels: one
    left out would keep an old build's code after an edit of it (distances.py went missing once its
    import line named more than `njit`)."""
    with_kernels = {p for p in cache.PLANNING_DIR.rglob("*.py") if "@njit(" in p.read_text()}
    assert with_kernels and with_kernels <= set(cache.kernel_sources())


def test_warm_needs_every_marker_newer_than_its_source(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert not warm.is_warm()
    for module, function in warm.MARKERS:
        source = cache.source_of(module)
        d = cache.cache_dir(source.parent)
        d.mkdir(parents=True, exist_ok=True)
        (d / f"{source.stem}.{function}-1.py311.nbi").write_bytes(b"")
    assert warm.is_warm()
    source = cache.source_of(warm.MARKERS[0][0])
    stale = source.stat().st_mtime - 60
    index = cache.cache_dir(source.parent) / f"{source.stem}.{warm.MARKERS[0][1]}-1.py311.nbi"
    os.utime(index, (stale, stale))
    assert not cache.cached(*warm.MARKERS[0]) and not warm.is_warm()


@pytest.mark.process
def test_one_compiler_at_a_time(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))   # a cold cache of the test's own
    assert not lock.busy()
    compiler = warm.start()
    try:
        assert compiler is not None
        # below the mission it shares the cores with, whether or not a plan will wait for it
        assert os.getpriority(os.PRIO_PROCESS, compiler.pid) == min(19, os.getpriority(os.PRIO_PROCESS, 0) + warm.NICE)
        # the lock was taken before the child started, and the child holds it
        assert lock.busy()
        assert warm.start() is None
        with lock.kernel_lock(wait=False) as mine:
            assert not mine
    finally:
        warm.stop(compiler)
    assert not lock.busy()
    with lock.kernel_lock(wait=False) as mine:
        assert mine
        assert warm.start() is None      # held here: nobody else starts compiling
