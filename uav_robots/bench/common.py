"""What every benchmark writes and reads the same way: markdown tables, CSV files, the results directory,
a list of sizes."""
from __future__ import annotations

import csv
import statistics
import sys
from pathlib import Path
from typing import Any, Iterable

from protocol.errors import UavRobotsError


def median_of(values: Iterable[float]) -> float | None:
    vals = [v for v in values if v is not None]
    return statistics.median(vals) if vals else None


def fmt(v: float | None, digits: int = 3) -> str:
    if v is None:
        return "-"
    return f"{v:.{digits}f}"


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with path.open("w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=keys)
        wr.writeheader()
        wr.writerows(rows)


def print_now(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def parse_sizes(text: str) -> list[int]:
    try:
        sizes = sorted({int(s) for s in text.split(",") if s.strip()})
    except ValueError:
        raise UavRobotsError(f"--sizes {text!r}: give comma-separated integers, e.g. 3,5,10") from None
    if not sizes or sizes[0] < 1:
        raise UavRobotsError(f"--sizes {text!r}: sizes must be at least 1")
    return sizes


def save_results(out: str, stem: str, markdown: str, summary: list[dict[str, Any]], runs: list[dict[str, Any]]) -> None:
    d = Path(out)
    try:
        d.mkdir(parents=True, exist_ok=True)
        (d / f"{stem}.md").write_text(markdown, encoding="utf-8")
        write_csv(d / f"{stem}.csv", summary)
        write_csv(d / f"{stem}-runs.csv", runs)
    except OSError as exc:
        raise UavRobotsError(f"cannot write benchmark results to {d}: {exc.strerror or exc}") from None
    print_now(f"wrote {d / (stem + '.md')}, {d / (stem + '.csv')}, {d / (stem + '-runs.csv')}")
