"""Argument types and the error line shared by `uav-robots plan` and `uav-robots bench`."""
from __future__ import annotations

import argparse
import sys


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be positive")
    return v


def seconds(text: str) -> float:
    """A finite, non-negative number of seconds (0: off)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 <= v < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} must be a finite number of seconds, 0 or more")
    return v


REFINE_HELP = ("then improve the plan for up to S more seconds by large-neighbourhood search (MAPF-LNS), "
               "within --time-limit; stops at once when no robot is delayed (default 0: off)")


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be at least 1")
    return v


def fail(exc: Exception) -> int:
    sys.stderr.write(f"error: {exc}\n")
    return 2
