"""Which robots share a process: the launcher starts one process per group, `secure init` makes one identity per group."""
from __future__ import annotations

import math


def robot_groups(n: int, per_process: int | None) -> list[list[int]]:
    """One process per robot for small fleets; pools beyond (one process per robot stops scaling near 100)."""
    if per_process is None:
        per_process = 1 if n <= 64 else math.ceil(n / 4)
    per_process = max(1, per_process)
    return [list(range(i, min(n, i + per_process))) for i in range(0, n, per_process)]
