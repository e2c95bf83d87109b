"""The scripts in examples/: each run as a newcomer runs it (`python3 examples/NAME.py` from the repository's
root, a real process), and what it prints checked, so that an example that stops working fails here."""
from __future__ import annotations

import os
import re
import select
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"
# The minimal robot's core rules: the whole single-robot suite takes about a minute (examples/README.md).
CORE_RULES = ("liveliness or acknowledged or malformed or follow_the_plan or refused_move or naming_the_robot "
              "or garbage or duplicate or exits_on or goes_away or states_only or repair")


def run(argv: list[str], timeout: float) -> subprocess.CompletedProcess:
    """`argv` in the repository's root, in a process group of its own: on a timeout the group is killed
    (an example's own children included) and the test fails saying what it printed."""
    proc = subprocess.Popen(argv, cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"{' '.join(argv[1:])} did not finish within {timeout:g} s; it printed:\n{out[-3000:]}")
    return subprocess.CompletedProcess(argv, proc.returncode, out, "")


def example(name: str, *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return run([sys.executable, f"examples/{name}", *args], timeout)


def succeeded(result: subprocess.CompletedProcess) -> str:
    assert result.returncode == 0, f"exit code {result.returncode}:\n{result.stdout[-3000:]}"
    return result.stdout


def test_every_example_is_listed_in_the_readme_and_names_no_path_of_this_machine():
    scripts = sorted(p.name for p in EXAMPLES.glob("*.py"))
    assert len(scripts) >= 5, scripts
    readme = (EXAMPLES / "README.md").read_text()
    for name in scripts:
        assert f"]({name})" in readme and f"python3 examples/{name}" in readme, f"{name} is not in examples/README.md"
    assert "(examples/README.md)" in (REPO / "README.md").read_text(), "README.md does not link examples/README.md"
    for path in [*EXAMPLES.glob("*.py"), EXAMPLES / "README.md", Path(__file__)]:
        text = path.read_text()
        assert str(REPO) not in text and not re.search(r"/(root|home|tmp)/", text), f"{path.name}: an absolute path"


@pytest.mark.process
def test_plan_movingai_plans_and_validates_a_shipped_instance():
    out = succeeded(example("plan_movingai.py"))
    assert "warehouse-10-20-10-2-1 (161x63), scenario random-1: 50 agents, planner lacam" in out
    assert "validated: 50 paths" in out
    m = re.search(r"makespan (\d+), sum of costs (\d+) \(lower bound (\d+)\)", out)
    assert m, out
    makespan, soc, lower_bound = map(int, m.groups())
    assert 0 < makespan <= soc and soc >= lower_bound > 0


@pytest.mark.process
def test_plan_movingai_says_in_one_line_what_is_wrong():
    result = example("plan_movingai.py", "--scen", "random-99")
    assert result.returncode != 0
    assert result.stdout.strip().splitlines() == [
        "plan_movingai: no shipped scenario 'random-99' for the map 'warehouse-10-20-10-2-1' (see scenarios/data/movingai)"]


@pytest.mark.slow
@pytest.mark.process
def test_the_minimal_robot_keeps_the_core_rules_of_the_conformance_suite():
    cmd = f"{shlex.quote(sys.executable)} examples/minimal_robot.py --id {{id}} --fleet {{fleet}} --connect {{endpoint}}"
    out = succeeded(run([sys.executable, "-m", "uav_robots", "conformance", "robot", "--cmd", cmd, "-k", CORE_RULES],
                        timeout=240))
    passed = re.search(r"(\d+) passed", out)
    assert passed and int(passed[1]) >= 20 and "failed" not in out and "error" not in out.split("passed")[-1], out[-3000:]
    assert "keeps protocol 2 (stated in its first PlanAck)" in out


@pytest.mark.slow
@pytest.mark.process
def test_minimal_robots_complete_a_real_mission_in_place_of_ours():
    out = succeeded(example("minimal_robot.py", timeout=150))
    assert re.search(r"^mission COMPLETED: 3/3 robots verified on their goals by the camera in \d+ ticks, collisions 0$",
                     out, re.M), out
    assert "3 minimal robots (examples/minimal_robot.py) completed a mission of our UAV and world" in out


@pytest.mark.slow
@pytest.mark.process
def test_fly_vehicle_mavsdk_takes_off_flies_and_lands():
    out = succeeded(example("fly_vehicle_mavsdk.py"))
    assert re.search(r"^connected: autopilot 1 \(PX4\), home 47\.397742 8\.545594", out, re.M), out
    assert re.search(r"^armed$", out, re.M)
    up = re.search(r"^took off: ([\d.]+) m above home, in the air: True$", out, re.M)
    assert up and abs(float(up[1]) - 10.0) < 0.5, out
    there = re.search(r"^flew to N (-?[\d.]+) E (-?[\d.]+) m at ([\d.]+) m", out, re.M)
    assert there and [round(float(v)) for v in there.groups()] == [-20, 15, 10], out
    assert re.search(r"^landed and disarmed: the simulator has it on the ground at N -20\.0 E 15\.0 \(altitude 0\.0 m\)",
                     out, re.M), out
    assert "MAVSDK version" not in out, "MAVSDK's own log lines are not the example's output"


@pytest.mark.process
def test_new_planner_plans_what_the_validator_accepts_and_shortest_paths_do_not():
    out = succeeded(example("new_planner.py"))
    assert "random-32-32-20, scenario random-1: 20 robots, 4-connected" in out
    assert re.search(r"^each robot alone \(not a MAPF plan\) +INVALID, \d+ violations, first: robots", out, re.M), out
    ours = re.search(r"^prioritized_astar \(this example\) +valid; makespan (\d+), sum of costs (\d+)", out, re.M)
    assert ours and int(ours[2]) >= int(ours[1]) > 0, out
    assert "the new planner's plan passed the independent validator" in out


@pytest.mark.slow
@pytest.mark.process
def test_observer_beside_a_run_sees_its_ticks_states_flags_and_end():
    mission = subprocess.Popen([sys.executable, "-m", "uav_robots", "run", "--robots", "3", "--camera", "ideal",
                                "--timeout", "120"], cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        ready, _, _ = select.select([mission.stdout], [], [], 60)
        first = mission.stdout.readline() if ready else ""
        found = re.search(r"fleet (\S+), zenoh (\S+),", first)
        assert found, f"uav-robots run's first line names no fleet and endpoint: {first!r}"
        out = succeeded(example("observe_fleet.py", "--connect", found[2], "--fleet", found[1], "--timeout", "120",
                                timeout=150))
        rest, _ = mission.communicate(timeout=60)
    finally:
        if mission.poll() is None:
            os.killpg(mission.pid, signal.SIGKILL)
            mission.communicate()
    assert mission.returncode == 0, rest[-3000:]
    ticks = int(re.search(r"^mission COMPLETED: 3/3 robots .* in (\d+) ticks", rest, re.M)[1])
    assert f"observer: joined fleet {found[1]} at {found[2]}" in out
    assert re.search(r"^phase \w+", out, re.M), out
    assert f"tick {ticks}/{ticks} of plan " in out
    # It joins as the mission starts: on a loaded machine the first ticks may pass before it listens.
    saw = re.search(r"^observer: saw (\d+) ticks, (\d+) robot states, 3 done flags$", out, re.M)
    assert saw and 0 < int(saw[1]) <= ticks and int(saw[2]) == 3 * int(saw[1]), out
    for robot in range(3):
        assert re.search(rf"^robot {robot} raised its flag: on its goal \(\d+, \d+\) at tick \d+$", out, re.M), out
        assert re.search(rf"^robot {robot}: {saw[1]} states, .*\(done\)$", out, re.M), out
    assert out.rstrip().endswith("mission end: completed")


@pytest.mark.slow
@pytest.mark.process
def test_observer_alone_starts_a_mission_and_watches_it():
    out = succeeded(example("observe_fleet.py", timeout=150))
    saw = re.search(r"^observer: saw (\d+) ticks, (\d+) robot states, 3 done flags$", out, re.M)
    assert saw and int(saw[1]) > 0 and int(saw[2]) == 3 * int(saw[1]), out
    assert "mission end: completed" in out
    assert re.search(r"^uav-robots run said: mission COMPLETED: 3/3 robots", out, re.M), out
