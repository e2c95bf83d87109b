"""Refinement of a plan by large-neighbourhood search: pure functions, then the command."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from protocol.mapfile import read_map, read_scen
from scenarios.benchmarks import movingai_map, movingai_scen
from uav_agent.planning.pipeline import plan_mission
from uav_agent.planning.mapf.refine import improve
from uav_agent.planning.types import Problem, sum_of_costs
from uav_agent.planning.validator import check

REPO = Path(__file__).resolve().parents[3]
MAP = "warehouse-10-20-10-2-1"


def test_a_detour_is_cut_to_the_shortest_path():
    free = np.ones((5, 6), dtype=bool)
    free[1:4, 2] = False
    problem = Problem(free, [(0, 2), (5, 0)], [(4, 2), (5, 4)])
    # robot 0 steps away and back before going round the wall; robot 1 waits twice on the way
    detour = [(0, 2), (0, 1), (0, 2), (0, 3), (0, 4), (1, 4), (2, 4), (3, 4), (3, 3), (3, 2), (4, 2)]
    waits = [(5, 0), (5, 0), (5, 1), (5, 1), (5, 2), (5, 3), (5, 4)]
    check(problem, [detour, waits])
    better, rounds = improve(problem, [detour, waits], 2.0)
    check(problem, better)
    assert rounds >= 1
    assert sum_of_costs([detour, waits], problem.goals) == 10 + 6
    assert sum_of_costs(better, problem.goals) == 8 + 4      # each robot's shortest path


def test_refinement_never_costs_more_and_stops_at_the_bound():
    free = read_map(movingai_map(MAP))
    agents = read_scen(movingai_scen(MAP, "random-1"), free, 200)
    starts, goals = [a.start for a in agents], [a.goal for a in agents]
    r = plan_mission(free, starts, goals, assign="none", refine_s=0.3)
    check(Problem(free, starts, goals), r.paths)
    assert r.metrics["lower_bound"] <= r.metrics["sum_of_costs"] <= r.metrics["initial_sum_of_costs"]
    assert r.metrics["refine_rounds"] >= 1 and r.timings["refinement"] < 1.0
    # a plan already at the lower bound is left as it is, at once
    few = plan_mission(free, starts[:5], goals[:5], assign="none", refine_s=30.0)
    assert few.metrics["soc_over_lb"] == 1.0 and few.metrics["refine_rounds"] == 0
    assert few.timings["refinement"] < 5.0
    # without --refine nothing changes
    plain = plan_mission(free, starts, goals, assign="none")
    assert "initial_sum_of_costs" not in plain.metrics and "refinement" not in plain.timings
    assert plain.metrics["sum_of_costs"] == r.metrics["initial_sum_of_costs"]


@pytest.mark.process
def test_the_command_refines_and_refuses_a_bad_budget(tmp_path):
    m, s = movingai_map(MAP), movingai_scen(MAP, "random-2")
    out = tmp_path / "plan.json"
    cmd = [sys.executable, "-m", "uav_robots", "plan", "--map", str(m), "--scen", str(s), "--agents", "150",
           "--out", str(out)]
    run = subprocess.run(cmd + ["--refine", "0.3"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "sum of costs before refinement" in run.stdout
    metrics = json.loads(out.read_text())["metrics"]
    assert metrics["sum_of_costs"] <= metrics["initial_sum_of_costs"]
    for bad in ("-1", "nan", "inf", "soon"):
        run = subprocess.run(cmd + ["--refine", bad], cwd=REPO, capture_output=True, text=True, timeout=60)
        assert run.returncode == 2 and "--refine" in run.stderr.strip().splitlines()[-1], (bad, run.stderr)
