"""`uav-robots plan` and `uav-robots bench`, through the handlers and as real subprocesses."""
from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from protocol.mapfile import ScenAgent, write_map, write_scen
from scenarios.maps import NAMED, place, warehouse
from uav_agent.planning.compile import cache
from uav_agent.planning.plan_io import read_plan
from uav_robots import cli

REPO = Path(__file__).resolve().parents[2]


def run_cli(*argv: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return run_cli_env({}, *argv, timeout=timeout)


def run_cli_env(env: dict[str, str], *argv: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "uav_robots", *argv], cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO), **env}, capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture
def small_files(tmp_path):
    free = warehouse(**NAMED["warehouse-small"])
    pl = place(free, 5, 1)
    write_map(tmp_path / "small.map", free)
    write_scen(tmp_path / "small.scen", "small.map", free, [ScenAgent(s, g) for s, g in zip(pl.starts, pl.goals)])
    return tmp_path, free, pl


@pytest.mark.process
def test_plan_subprocess_end_to_end(small_files):
    d, free, pl = small_files
    out = d / "plan.json"
    p = run_cli("plan", "--map", str(d / "small.map"), "--robots", "5", "--seed", "1", "--out", str(out))
    assert p.returncode == 0, p.stderr
    assert "sum of costs" in p.stdout and "time: total" in p.stdout
    plan = read_plan(out)
    assert sorted(plan.starts) == sorted(pl.starts) and sorted(plan.goals) == sorted(pl.goals)
    assert plan.planner == "lacam" and np.array_equal(plan.free, free)


@pytest.mark.slow
@pytest.mark.process
def test_plan_on_a_fresh_clone_does_not_wait_for_the_compile(tmp_path):
    """An empty numba cache (and so no build): the planners run interpreted and give the plan the
    compiled kernels give, 50 robots on the 450 warehouse, without compiling first."""
    cold = run_cli_env({"NUMBA_CACHE_DIR": str(tmp_path / "cold")}, "plan", "--map", "warehouse-450", "--robots", "50",
                       "--out", str(tmp_path / "cold.json"))
    assert cold.returncode == 0, cold.stderr[-2000:]
    assert "planning with them interpreted" in cold.stdout and "compiling" not in cold.stdout
    warm_run = run_cli("plan", "--map", "warehouse-450", "--robots", "50", "--out", str(tmp_path / "warm.json"))
    assert warm_run.returncode == 0 and "interpreted" not in warm_run.stdout
    a, b = read_plan(tmp_path / "cold.json"), read_plan(tmp_path / "warm.json")
    assert a.paths == b.paths and a.metrics == b.metrics


@pytest.mark.process
def test_plan_subprocess_bad_map_exits_2(tmp_path):
    bad = tmp_path / "bad.map"
    bad.write_text("type octile\nheight 3\nwidth 4\nmap\n....\n..\n")
    p = run_cli("plan", "--map", str(bad), "--robots", "2", "--out", str(tmp_path / "p.json"))
    assert p.returncode == 2
    assert p.stderr.startswith("error: ") and len(p.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "p.json").exists()


def test_plan_scen_keeps_pairs_unless_asked(small_files, capsys):
    d, free, pl = small_files
    out = d / "scen-plan.json"
    assert cli.main(["plan", "--map", str(d / "small.map"), "--scen", str(d / "small.scen"),
                          "--agents", "4", "--out", str(out), "--planner", "pibt"]) == 0
    plan = read_plan(out)
    assert plan.starts == pl.starts[:4] and plan.goals == pl.goals[:4]
    assert cli.main(["plan", "--map", str(d / "small.map"), "--scen", str(d / "small.scen"),
                          "--assign", "optimal", "--out", str(out), "--connectivity", "8"]) == 0
    plan = read_plan(out)
    assert plan.connectivity == 8 and plan.starts == pl.starts and sorted(plan.goals) == sorted(pl.goals)
    assert "wrote" in capsys.readouterr().out


def test_a_shipped_movingai_map_and_its_scenario_by_name(tmp_path):
    from protocol.mapfile import read_scen
    from scenarios.benchmarks import movingai_scen

    out = tmp_path / "p.json"
    assert cli.main(["plan", "--map", "room-64-64-8", "--scen", "random-1", "--agents", "12", "--out", str(out)]) == 0
    agents = read_scen(movingai_scen("room-64-64-8", "random-1"), None, 12)
    plan = read_plan(out)
    assert plan.starts == [a.start for a in agents] and plan.goals == [a.goal for a in agents]


def test_plan_map_spec_and_fallback_note(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert cli.main(["plan", "--map", "random:width=12,height=10,density=0.1", "--robots", "6",
                          "--seed", "4", "--planner", "paper-prm", "--out", str(out)]) == 0
    assert read_plan(out).map_name.startswith("random:")
    # A head-on corridor: the paper's pipeline cannot, the default planner can.
    free = np.zeros((2, 7), dtype=bool)
    free[0, :] = True
    free[1, 3] = True
    write_map(tmp_path / "c.map", free)
    write_scen(tmp_path / "c.scen", "c.map", free, [ScenAgent((0, 0), (6, 0)), ScenAgent((6, 0), (0, 0))])
    args = ["plan", "--map", str(tmp_path / "c.map"), "--scen", str(tmp_path / "c.scen"),
            "--planner", "paper-astar", "--out", str(out)]
    capsys.readouterr()
    assert cli.main(args) == 0
    assert "fell back" in capsys.readouterr().out
    assert cli.main(args + ["--no-fallback"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1


@pytest.fixture
def bad_files(small_files):
    d, free, pl = small_files
    rooms = np.ones((4, 9), dtype=bool)
    rooms[:, 4] = False                     # a wall: the goal is in the other room
    write_map(d / "rooms.map", rooms)
    write_scen(d / "rooms.scen", "rooms.map", rooms, [ScenAgent((0, 0), (8, 3))])
    write_scen(d / "bad.scen", "small.map", free, [ScenAgent(pl.starts[0], (0, 0))])   # (0, 0) is the wall
    return {"SMALL": str(d / "small.map"), "SCEN": str(d / "small.scen"), "BADSCEN": str(d / "bad.scen"),
            "ROOMS": str(d / "rooms.map"), "ROOMSCEN": str(d / "rooms.scen"), "OUT": str(d / "p.json")}


@pytest.mark.parametrize("argv, match", [
    (["--map", "missing.map", "--robots", "2"], "map file not found"),
    (["--map", "nosuchmap", "--robots", "2"], "unknown map"),
    (["--map", "SMALL", "--robots", "2", "--planner", "dijkstra"], "unknown planner 'dijkstra'"),
    (["--map", "SMALL", "--robots", "5000"], "free connected cells"),
    (["--map", "ROOMS", "--scen", "ROOMSCEN"], r"cannot reach its goal \(8, 3\)"),
    (["--map", "SMALL", "--scen", "missing.scen"], "scenario file not found"),
    (["--map", "SMALL", "--scen", "BADSCEN"], r"goal \(0, 0\) is not a free cell"),
    (["--map", "SMALL", "--scen", "SCEN", "--agents", "99"], "asked for 99 agents"),
    (["--map", "SMALL", "--robots", "2", "--agents", "2"], "--agents goes with --scen"),
    (["--map", "SMALL", "--robots", "12", "--assign", "bruteforce"], "brute-force"),
])
def test_plan_bad_input_exits_2_with_one_line(bad_files, capsys, argv, match):
    argv = ["plan", *(bad_files.get(a, a) for a in argv), "--out", bad_files["OUT"]]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1
    assert re.search(match, err), err
    assert not Path(bad_files["OUT"]).exists()


# ---------------------------------------------------------------------------- bench

@pytest.fixture
def paper_data(tmp_path):
    """The paper bench's file layout with a small warehouse, so that a test run takes seconds."""
    free = warehouse(**NAMED["warehouse-small"])
    pl = place(free, 8, 2)
    d = tmp_path / "data" / "paper-warehouse-450"
    d.mkdir(parents=True)
    write_map(d / "warehouse-450.map", free)
    write_scen(d / "warehouse-450-random-1.scen", "warehouse-450.map", free,
               [ScenAgent(s, g) for s, g in zip(pl.starts, pl.goals)])
    return tmp_path / "data"


@pytest.mark.slow
@pytest.mark.process
def test_bench_paper_subprocess(paper_data, tmp_path):
    out = tmp_path / "out"
    p = run_cli("bench", "paper", "--sizes", "3,5", "--repeat", "1", "--data", str(paper_data),
                "--out", str(out), timeout=240)
    assert p.returncode == 0, p.stderr
    md = (out / "paper.md").read_text()
    assert "| paper-astar | 3 | 1/1 |" in md and "| default (lacam) | 5 | 1/1 |" in md
    assert "9.549" in md and "first call" in md
    rows = list(csv.DictReader((out / "paper.csv").open()))
    assert {(r["pipeline"], r["agents"]) for r in rows} == {
        (p, n) for p in ("paper-astar", "paper-prm", "default") for n in ("3", "5")}
    for r in rows:
        assert r["solved"] == "1" and float(r["soc_over_lb"]) >= 1.0 and float(r["peak_rss_mb"]) > 10
        assert float(r["total_s"]) >= float(r["planning_s"]) > 0
    assert md.splitlines()[2] in p.stdout


@pytest.mark.process
def test_bench_paper_timeout_skips_larger_sizes(paper_data, tmp_path):
    out = tmp_path / "out"
    p = run_cli("bench", "paper", "--sizes", "3,5", "--repeat", "2", "--pipelines", "default",
                "--time-limit", "0.000001", "--data", str(paper_data), "--out", str(out),
                timeout=240)
    assert p.returncode == 0, p.stderr
    runs = list(csv.DictReader((out / "paper-runs.csv").open()))
    status = sorted((r["agents"], r["status"]) for r in runs)
    assert status == [("3", "skipped"), ("3", "timeout"), ("5", "skipped"), ("5", "skipped")]


@pytest.mark.process
def test_bench_movingai_subprocess(tmp_path):
    out = tmp_path / "out"
    p = run_cli("bench", "movingai", "--maps", "random-32-32-20", "--scens", "random-1..2", "--agents", "5,10",
                "--out", str(out), timeout=240)
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader((out / "movingai.csv").open()))
    assert [(r["agents"], r["solved"], r["runs"]) for r in rows] == [("5", "2", "2"), ("10", "2", "2")]
    assert all(float(r["soc_over_lb"]) >= 1.0 for r in rows)
    runs = list(csv.DictReader((out / "movingai-runs.csv").open()))
    assert {r["scen"] for r in runs} == {"random-1", "random-2"}


@pytest.mark.slow
@pytest.mark.process
def test_bench_command_times_whole_processes(paper_data, tmp_path):
    out = tmp_path / "out"
    p = run_cli("bench", "command", "--sizes", "3,5", "--repeat", "2", "--data", str(paper_data),
                "--out", str(out), timeout=240)
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader((out / "command.csv").open()))
    assert [r["agents"] for r in rows] == ["3", "5"]
    for r in rows:
        # A whole process holds its own in-process time and more (at least the interpreter's start).
        assert float(r["median_wall_s"]) > float(r["median_in_process_s"]) > 0
        assert float(r["min_wall_s"]) <= float(r["median_wall_s"]) <= float(r["max_wall_s"])
    assert rows[0]["lacam3_whole_s"] == "0.11" and rows[1]["lacam3_whole_s"] == ""
    runs = list(csv.DictReader((out / "command-runs.csv").open()))
    assert len(runs) == 4 * (2 if cache.built() else 1)
    assert "whole command" in (out / "command.md").read_text()


@pytest.mark.parametrize("argv, match", [
    (["bench", "command", "--sizes", "0"], "--sizes"),
    (["bench", "paper", "--sizes", "3,x"], "--sizes"),
    (["bench", "paper", "--pipelines", "default,warp"], "unknown planner"),
    (["bench", "paper", "--data", "/nonexistent"], "benchmark file not found"),
    (["bench", "movingai", "--scens", "rnd1"], "--scens"),
    (["bench", "movingai", "--maps", "atlantis"], "benchmark file not found: "),
])
def test_bench_bad_arguments(argv, match, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and match in err and len(err.strip().splitlines()) == 1
