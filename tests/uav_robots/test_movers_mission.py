"""Whole missions among people, forklifts and pallets (issue 32): real processes, the world's camera
drawing the movers, the UAV seeing them in its own images and repairing its plan before every tick;
the world's record is the judge (no robot-mover contact, no collision)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from scenarios.floor import setup_floor
from uav_agent.report import load_report

pytestmark = [pytest.mark.process, pytest.mark.slow]

CLI = [sys.executable, "-m", "uav_robots", "run"]


def _run(tmp_path, *args, timeout=300):
    out = tmp_path / "out"
    proc = subprocess.run([*CLI, "--out", str(out), *args], capture_output=True, text=True, timeout=timeout)
    return proc, load_report(out)


def _safe(report):
    assert report["mover_collisions"] == 0 and report["collisions"] == 0, report["truth"]["movers"]["contacts"]
    watch = report["mover_watch"]
    assert watch["looks"] >= report["ticks"] // watch["look_every"] - 1
    trace = report["truth"]["movers"]["trace"]
    assert all(len(cells) == report["ticks"] + 1 for cells in trace.values())
    # No robot ever ended a tick on a cell a mover held after it: the record, cell by cell.
    executed = report["executed"]
    for t in range(report["ticks"] + 1):
        movers = {tuple(cells[t]) for cells in trace.values()}
        robots = {tuple(cells[min(t, len(cells) - 1)]) for cells in executed.values()}
        assert not movers & robots, f"tick {t}: a robot on a mover's cell"


def test_forklifts_and_pallets_are_seen_and_never_touched_while_robots_crash_and_stall(tmp_path):
    proc, report = _run(tmp_path, "--robots", "12", "--seed", "1", "--movers", "4", "--mover-speed", "2",
                        "--scene", "pallets=2", "--tick-timeout", "3", "--fault", "crash:3@4", "--fault", "stall:6@2:3")
    assert proc.returncode in (0, 3), proc.stderr[-2000:]   # robot 3 crashed for good: degraded at worst
    assert report["movers"] == 6
    _safe(report)
    assert report["mover_watch"]["repair_ms_max"] < 50
    assert 3 in report["lost"] or 3 in report["quarantined"]
    kinds = {e["what"] for e in report["events"] if e["kind"] == "movers"}
    assert any("forklift" in w and "pallet" in w for w in kinds)


def test_a_pallet_dropped_on_a_goal_leaves_it_unserved_and_the_mission_ends(tmp_path):
    floor = setup_floor("warehouse-small", 5, 8)
    # the goal farthest from every start: no robot reaches it before the pallet falls at tick 1
    goal = max(floor.goals, key=lambda g: min(abs(g[0] - s[0]) + abs(g[1] - s[1]) for s in floor.starts))
    routes = tmp_path / "routes.json"
    routes.write_text(json.dumps({"movers": [{"kind": "pallet", "at": list(goal), "tick": 1}]}))
    proc, report = _run(tmp_path, "--robots", "8", "--seed", "5", "--mover-routes", str(routes), "--look-every", "1")
    assert proc.returncode == 3, proc.stderr[-2000:]        # degraded: one goal could not be served
    assert report["outcome"] == "degraded" and report["unserved_goals"] == [list(goal)]
    assert [e for e in report["events"] if e["kind"] == "goal-under-mover"]
    assert sum(report["verified"].values()) == 7
    _safe(report)


def test_a_floor_one_image_does_not_hold_is_watched_from_a_tour(tmp_path):
    # A small camera makes a 174x34 floor two watch poses: each look rules movers out of its half only
    # (the vehicle's clock 30 times the wall's: the hops between them are what this waits for).
    proc, report = _run(tmp_path, "--camera", "ideal,width=1280,height=960", "--map", "warehouse:blocks_x=10,blocks_y=8",
                        "--robots", "8", "--movers", "4", "--time-scale", "30")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert report["completed"] is True and report["mover_watch"]["tour_poses"] == 2
    _safe(report)
