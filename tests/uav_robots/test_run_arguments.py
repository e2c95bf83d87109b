"""`uav-robots run` checks every input before it starts a process: one line, exit 2."""
import subprocess
import sys

import pytest

pytestmark = pytest.mark.process   # every test here starts a process


@pytest.mark.slow
@pytest.mark.parametrize("args, words", [
    (["--seed", "-1"], "--seed must be"),
    (["--robots", "0"], "--robots must be"),
    (["--time-scale", "0"], "--time-scale must be"),
    (["--time-scale", "nan"], "--time-scale must be"),
    (["--tick-timeout", "1"], "--tick-timeout must be"),
    (["--map", "warehouse:blocks_x=nan,blocks_y=3"], "not a finite number"),
    (["--map", "random:width=90000,height=90000"], "cells per side"),
    (["--map", "random:width=16000,height=16000"], "more than"),
    (["--camera", "width=100000,height=100000"], "too large"),
    (["--camera", "width=abc"], "not name=number"),
    (["--fault", "liar:99"], "no robot 99"),
    (["--planner", "warp"], "unknown planner"),
    (["--scene", "landmark_spacing=2"], "landmark_spacing 2 is not 0"),
    (["--camera", "goal_pads=1"], "goal_pads is not the camera's but the scene's"),
    (["--wobble", "40"], "--wobble must be"),
    (["--scen", "no-such.scen"], "no-such.scen"),
])
def test_bad_input_is_one_line_before_anything_starts(args, words):
    run = subprocess.run([sys.executable, "-m", "uav_robots", "run", *args], capture_output=True, text=True,
                         timeout=60)
    assert run.returncode == 2, (args, run.stdout[-500:], run.stderr[-500:])
    assert run.stdout == "", "a process was started or a header printed before the check"
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], lines


def test_a_scenario_of_another_map_names_that_map(tmp_path):
    from protocol.mapfile import ScenAgent, write_scen
    from scenarios.maps import resolve_map

    _, free = resolve_map("random:width=16,height=16,density=0.1")
    write_scen(tmp_path / "other.scen", "random-16", free, [ScenAgent((0, 0), (1, 1), 1.0)] * 8)
    run = subprocess.run([sys.executable, "-m", "uav_robots", "run", "--scen", str(tmp_path / "other.scen")],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert "is for the map 'random-16' of 16x16 cells, not this 24x18 floor" in run.stderr, run.stderr


def test_an_out_that_is_a_file_is_refused(tmp_path):
    f = tmp_path / "report"
    f.write_text("x")
    run = subprocess.run([sys.executable, "-m", "uav_robots", "run", "--out", str(f)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and "is a file" in run.stderr and len(run.stderr.strip().splitlines()) == 1
