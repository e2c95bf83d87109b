"""Small scenes the world and robot tests share."""
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
