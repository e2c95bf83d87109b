"""The floors hold (import-linter), no modules import one another in a circle, and the repository
names no path of any one machine."""
from __future__ import annotations

import functools
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.process   # every test here starts a process

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("protocol", "scenarios", "sim_world", "robot_agents", "uav_agent", "conformance", "uav_robots")


def _lint(root: Path) -> subprocess.CompletedProcess:
    # import-linter finds the packages on sys.path: `root` first, so a copy is linted, not the install.
    code = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
    return subprocess.run([sys.executable, "-c", code, "--config", str(root / "pyproject.toml"), "--no-cache"],
                          cwd=root, env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"},
                          capture_output=True, text=True, timeout=120)


def test_the_floors_hold():
    run = _lint(REPO)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "0 broken" in run.stdout


@pytest.mark.parametrize("file, line, broken", [
    ("protocol/keys.py", "import sim_world.service", "floors"),
    ("sim_world/moves.py", "from uav_agent import fleet", "floors"),
    ("robot_agents/robot.py", "import scenarios.maps", "a robot process imports nothing but the protocol"),
    ("uav_agent/fleet.py", "import uav_robots.run.launcher", "floors"),
    ("uav_robots/view/state.py", "import uav_robots.record.recording", "wings"),
    ("uav_robots/secure/fleet.py", "import uav_robots.bench.secure", "wings"),
    ("uav_robots/record/observer.py", "import uav_robots.secure.fleet", "wings"),
    # the planning package's wings: compile/ imports no planner, a kernel no portfolio, MAPF not the paper's
    ("uav_agent/planning/compile/cache.py", "from uav_agent.planning.mapf import lacam", "planning: build"),
    ("uav_agent/planning/mapf/pibt.py", "from uav_agent.planning import portfolio", "planning: build"),
    ("uav_agent/planning/mapf/sipp.py", "from uav_agent.planning.paper import astar", "planning: build"),
    ("uav_agent/planning/pipeline.py", "from uav_agent.planning.build import warm", "planning: build"),
])
def test_a_backward_import_breaks_the_contract(tmp_path, file, line, broken):
    for pkg in PACKAGES:
        shutil.copytree(REPO / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__", "data"))
    shutil.copy(REPO / "pyproject.toml", tmp_path / "pyproject.toml")
    target = tmp_path / file
    target.write_text(target.read_text() + f"\n{line}\n")
    run = _lint(tmp_path)
    assert run.returncode == 1, run.stdout[-3000:] + run.stderr[-2000:]
    assert re.search(re.escape(broken) + r".*BROKEN", run.stdout.replace("\n", " ")), run.stdout[-3000:]



def _circles(root: Path, packages: tuple[str, ...]) -> list[list[str]]:
    """The import circles among the modules of `packages` under `root`: each a strongly connected
    set (every module of it reaches every other), found by grimp, whose graph import-linter builds."""
    code = ("import json, sys, grimp\n"
            "g = grimp.build_graph(*sys.argv[1:], cache_dir=None)\n"
            "found = set()\n"
            "for m in g.modules:\n"
            "    both = g.find_downstream_modules(m) & g.find_upstream_modules(m)\n"
            "    if both:\n"
            "        found.add(tuple(sorted(both | {m})))\n"
            "print(json.dumps(sorted(found)))\n")
    run = subprocess.run([sys.executable, "-c", code, *packages], cwd=root,
                         env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"}, capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout)


@functools.lru_cache(maxsize=1)
def _circles_of_the_house() -> tuple[tuple[str, ...], ...]:
    return tuple(tuple(c) for c in _circles(REPO, PACKAGES))


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_circle(package):
    mine = [c for c in _circles_of_the_house() if any(m.split(".")[0] == package for m in c)]
    assert not mine, "modules that import one another: " + "; ".join(" <-> ".join(c) for c in mine)


def test_a_planted_circle_is_found(tmp_path):
    shutil.copytree(REPO / "sim_world", tmp_path / "sim_world", ignore=shutil.ignore_patterns("__pycache__"))
    assert _circles(tmp_path, ("sim_world",)) == []
    desk = tmp_path / "sim_world" / "desk.py"
    desk.write_text(desk.read_text() + "\nfrom .ahead import AheadDesk\n")
    assert _circles(tmp_path, ("sim_world",)) == [["sim_world.ahead", "sim_world.desk"]]

# A path that starts at the root of one machine's file system: its home, a workspace, a mount.
MACHINE_PATH = re.compile(r"(?<![\w.~-])/(work|root|home|Users|mnt|srv|opt)/[\w.-]")


def test_no_absolute_machine_path_in_the_repository():
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, capture_output=True,
                           text=True, timeout=30).stdout.split()
    if not files:
        pytest.skip("not a git checkout")
    hits = []
    for name in files:
        path = REPO / name
        if not path.is_file() or path.suffix in (".png", ".gif", ".mp4", ".mcap"):
            continue
        for no, text in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if MACHINE_PATH.search(text):
                hits.append(f"{name}:{no}: {text.strip()[:120]}")
    assert not hits, "absolute machine paths:\n" + "\n".join(hits)


def test_a_robot_process_loads_nothing_of_the_uav():
    code = ("import sys, runpy; sys.argv = ['robot_agents', '--help']\n"
            "try:\n    runpy.run_module('robot_agents', run_name='__main__')\nexcept SystemExit:\n    pass\n"
            f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({PACKAGES!r})))")
    run = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "['protocol', 'robot_agents']"
