"""The environment of a Python child that imports the planning package (compiler, interpreted
planner, build): ours, the extra variables asked for, and the package's root first on its path."""
from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(os.path.abspath(__file__)).parents[3]


def child_env(**extra: str) -> dict[str, str]:
    return {**os.environ, **extra, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
