"""The run spec (run.json) and the fault catalogue: one record of a run's configuration, read back
exactly; every fault kind one row, its grammar round-tripped; bad input one line."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest
from hypothesis import given, strategies as st

from protocol.errors import UavRobotsError
from protocol.faults import CATALOGUE, ROBOTS, VEHICLE, WORLD, Fault, help_line, parse_fault, split_faults, usage
from protocol.run_spec import (CameraSpec, LimitsSpec, PlanningSpec, RunSpec, SceneSpec, VehicleSpec, add_spec_argument,
                               apply_spec, given_flags, read_spec, spec_from_dict)


def a_spec() -> RunSpec:
    return RunSpec(map="warehouse-450", robots=50, seed=7, scen="floor.scen",
                   camera=CameraSpec("mavlink", "ideal,blur_sigma=2"), scene=SceneSpec(landmark_spacing=8, goal_pads=False),
                   vehicle=VehicleSpec(preset="indoor", time_scale=5.0, wobble_deg=1.0),
                   faults=("crash:3@10", "slip:0.05"),
                   planning=PlanningSpec(planner="pibt", assign="greedy", connectivity=8, time_limit_s=30.0,
                                         fallback=False),
                   limits=LimitsSpec(tick_timeout_s=4.0, monitor_every=0))


def test_a_spec_is_read_back_exactly(tmp_path):
    spec = a_spec()
    (tmp_path / "run.json").write_text(spec.to_json())
    assert read_spec(tmp_path / "run.json") == spec
    assert json.loads(spec.to_json())["format"] == "uav-robots-run/1"


@pytest.mark.parametrize("change, named", [
    ({"robots": "8"}, "robots"),
    ({"planning": {"connectivity": 4.5}}, "planning.connectivity"),
    ({"planning": {"connectivity": 6}}, "planning.connectivity is 6, not one of 4, 8"),
    ({"camera": {"source": "telepathy"}}, "camera.source is 'telepathy'"),
    ({"vehicle": {"preset": "underwater"}}, "vehicle.preset"),
    ({"camera": {"lens": "fisheye"}}, "lens"),
    ({"scene": {"goal_pads": 2}}, "scene.goal_pads is 2, not bool"),
    ({"scen": 3}, "scen is 3"),
    ({"faults": ["fly:1"]}, "--fault 'fly:1'"),
    ({"format": "something/2"}, "format"),
    ({"colour": "red"}, "colour"),
])
def test_a_bad_spec_is_one_line_naming_the_field(tmp_path, change, named):
    data = {**a_spec().as_dict(), **change}
    with pytest.raises(UavRobotsError) as e:
        spec_from_dict(data)
    assert named in str(e.value) and "\n" not in str(e.value)


def test_a_spec_that_is_not_json_is_one_line(tmp_path):
    (tmp_path / "run.json").write_text("{not json")
    with pytest.raises(UavRobotsError, match="not JSON") as e:
        read_spec(tmp_path / "run.json")
    assert "\n" not in str(e.value)


def test_the_spec_fills_what_the_command_line_did_not_give(tmp_path):
    (tmp_path / "run.json").write_text(a_spec().to_json())
    p = argparse.ArgumentParser()
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--connectivity", type=int, default=4)
    add_spec_argument(p)
    argv = ["--spec", str(tmp_path / "run.json"), "--connectivity=4"]
    args = p.parse_args(argv)
    args.given_flags = given_flags(argv)
    fields = {"--seed": lambda s: s.seed, "--connectivity": lambda s: s.planning.connectivity}
    assert apply_spec(args, fields) == a_spec()
    assert (args.seed, args.connectivity) == (7, 4)     # the spec's seed; the flag given wins


def test_every_fault_kind_is_one_row_named_unit_dot_kind():
    names = [k.name for k in CATALOGUE]
    assert names == ["robot.crash", "robot.stall", "robot.liar", "world.slip", "world.skid", "vehicle.battery",
                     "camera.off", "camera.stuck", "link.mavlink"]
    assert all(k.form in help_line() and k.help in help_line() for k in CATALOGUE)
    assert usage(ROBOTS) == "crash:ROBOT@TICK, stall:ROBOT@TICK:TICKS or liar:ROBOT"


@given(kind=st.sampled_from(CATALOGUE), robot=st.integers(0, 999), tick=st.integers(1, 10**6),
       ticks=st.integers(1, 1000), p=st.sampled_from([0.0, 0.05, 0.5, 1.0]), pct=st.integers(0, 100),
       seconds=st.integers(0, 3600), duration=st.integers(1, 3600))
def test_every_fault_spec_round_trips(kind, robot, tick, ticks, p, pct, seconds, duration):
    text = (kind.form.replace("ROBOT", str(robot)).replace("TICKS", str(ticks)).replace("TICK", str(tick))
            .replace("PCT", str(pct)).replace("SECONDS", str(seconds)).replace("DURATION", str(duration))
            .replace("P", f"{p:g}"))
    fault = parse_fault(text)
    assert str(fault) == text and fault.injector == kind.injector and fault.kind == kind.kind


def test_faults_go_to_the_process_that_injects_them():
    split = split_faults(["crash:1@5", "slip:0.1", "skid:2@3", "liar:0", "battery:20@30"])
    assert split[ROBOTS] == [Fault("crash", 1, 5), Fault("liar", 0)]
    assert split[WORLD] == [Fault("slip", p=0.1), Fault("skid", 2, 3)]
    assert split[VEHICLE] == [Fault("battery", pct=20, seconds=30)]
    with pytest.raises(UavRobotsError, match="at most 100"):
        parse_fault("battery:101@3")
    with pytest.raises(UavRobotsError, match="give crash:ROBOT@TICK, stall:ROBOT@TICK:TICKS or liar:ROBOT"):
        parse_fault("slip:0.1", ROBOTS)
    with pytest.raises(UavRobotsError, match="P in \\[0, 1\\]"):
        parse_fault("slip:1.5")


def _uav_robots(argv: list[str], timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "uav_robots", *argv], capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.process
@pytest.mark.parametrize("spec, words", [
    ({"robots": "eight"}, "robots is 'eight'"),
    ({"planning": {"assign": "magic"}}, "--assign 'magic': one of"),   # the command's own choices, checked
    ({"scene": {"landmark_spacing": 2}}, "--scene 'landmark_spacing=2,goal_pads=1': landmark_spacing 2 is not 0"),
    ({"vehicle": {"wobble_deg": 45.0}}, "--wobble must be a number in [0, 30]"),
])
def test_a_bad_spec_file_is_one_line_and_exit_2(tmp_path, spec, words):
    (tmp_path / "run.json").write_text(json.dumps({"format": "uav-robots-run/1", **spec}))
    res = _uav_robots(["run", "--spec", str(tmp_path / "run.json")], 60)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert words in res.stderr


@pytest.mark.slow
@pytest.mark.process
def test_a_run_is_repeated_from_its_spec(tmp_path):
    """`run --spec OUT/run.json` repeats the run: the same spec (seed, scenario, scene, faults, planner),
    the same plan, and report.json carries the spec; a flag given beside --spec still wins."""
    from protocol.mapfile import ScenAgent, write_scen
    from scenarios.maps import place, resolve_map

    _, free = resolve_map("warehouse-small")
    placed = place(free, 4, 11)
    write_scen(tmp_path / "four.scen", "warehouse-small", free,
               [ScenAgent(s, g, 0.0) for s, g in zip(placed.starts, placed.goals)])
    first, again = tmp_path / "first", tmp_path / "again"
    res = _uav_robots(["run", "--robots", "4", "--seed", "5", "--fault", "crash:0@3", "--planner", "pibt",
                       "--camera", "ideal", "--scene", "landmark_spacing=8", "--wobble", "0.5",
                       "--scen", str(tmp_path / "four.scen"), "--out", str(first), "--quiet"], 300)
    assert res.returncode == 3, res.stderr[-2000:]
    spec = read_spec(first / "run.json")
    assert (spec.robots, spec.seed, spec.faults, spec.planning.planner) == (4, 5, ("crash:0@3",), "pibt")
    assert (spec.scene, spec.vehicle.wobble_deg) == (SceneSpec(landmark_spacing=8, goal_pads=False), 0.5)
    report = json.loads((first / "report.json").read_text())
    assert report["run"] == spec.as_dict()
    # The scenario's starts, and the scene's landmarks that the ideal camera's floor would not have.
    assert [tuple(report["truth"]["robots"][str(i)]) for i in range(4)] == placed.starts
    assert report["perceived"]["registration"]["by_landmarks"] >= 1
    res = _uav_robots(["run", "--spec", str(first / "run.json"), "--out", str(again), "--quiet"], 300)
    assert res.returncode == 3, res.stderr[-2000:]
    assert (again / "run.json").read_text() == (first / "run.json").read_text()
    paths = [{r["id"]: r["path"] for r in json.loads((d / "plan.json").read_text())["robots"]} for d in (first, again)]
    assert paths[0] == paths[1]
    res = _uav_robots(["run", "--spec", str(first / "run.json"), "--fault", "crash:1@2", "--out", str(again),
                       "--quiet"], 300)
    assert read_spec(again / "run.json").faults == ("crash:1@2",)
