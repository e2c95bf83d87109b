"""Small scenes the world and robot tests share."""
import subprocess
import sys
from pathlib import Path

import numpy as np

from protocol.mapfile import ScenAgent, write_map, write_scen


def open_map(tmp_path: Path, starts, goals, w=8, h=6) -> tuple[str, str]:
    """An obstacle-free map with a scenario, so tests choose where robots stand."""
    free = np.ones((h, w), dtype=bool)
    write_map(tmp_path / "open.map", free)
    write_scen(tmp_path / "open.scen", "open.map", free,
               [ScenAgent(tuple(a), tuple(b)) for a, b in zip(starts, goals)])
    return str(tmp_path / "open.map"), str(tmp_path / "open.scen")


def robot_process(hub, ids: str) -> subprocess.Popen:
    """Our robot process hosting `ids` on the hub's fleet, its first line read: "ready"."""
    proc = subprocess.Popen([sys.executable, "-m", "robot_agents", "--ids", ids, "--fleet", hub.fleet, "--connect",
                             hub.endpoint], cwd=Path(__file__).resolve().parents[1], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    noun = "robot" if "-" not in ids and "," not in ids else "robots"
    line = proc.stdout.readline().strip()
    assert line == f"{noun} {ids} ready (fleet {hub.fleet})", line
    return proc
