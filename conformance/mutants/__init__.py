"""Mutants: our own robot or UAV with exactly one protocol rule broken, to prove the suites catch it.

`runner` is the command (`python -m conformance.mutants robot|uav --break ID ...`); the
mutants themselves are in one module per family: `robot_lifecycle`, `robot_plans`,
`robot_ticks`, `robot_messages` and `uav`, each made of the helpers in `patching`.
"""
from __future__ import annotations

from .runner import SIDES, breaks, main

__all__ = ["SIDES", "breaks", "main"]
