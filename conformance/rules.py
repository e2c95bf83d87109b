"""The rules of docs/protocol.md that a robot or a UAV must keep, with the tests that check each.

One table, three readers: docs/conformance-rules.md is written from it
(`python -m conformance.rules --write`; a test fails while the file differs),
`uav-robots conformance --list-rules` prints it, and the mutation test
(tests/conformance/test_conformance_mutants.py) breaks each rule in a copy of our own robot
or UAV (`conformance.mutants`) and runs exactly the tests listed here, which
must then fail. The rows are in `robot_rules.py` and `uav_rules.py`, a row is a `rule.Rule`.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .robot_rules import ROBOT_RULES
from .rule import E, F, K, M, S, W, Rule
from .uav_rules import UAV_RULES

__all__ = ["DOC", "RULES", "UNCHECKED", "Rule", "markdown", "newer_rules", "rule", "rules", "since_of_test",
           "text_table"]

DOC = Path(__file__).resolve().parents[1] / "docs" / "conformance-rules.md"
RULES: tuple[Rule, ...] = ROBOT_RULES + UAV_RULES


# What docs/protocol.md asks of a robot that the suite does not check, and why (side, section, what, why).
UNCHECKED: tuple[tuple[str, str, str, str], ...] = (
    ("robot", S, "without a router for 20 s it exits 1 with one line",
     "it takes 20 s; R70 checks the wait itself"),
    ("robot", K, "queries use Zenoh's default options (target best matching, consolidation auto)",
     "a queryable is not told the options of the query it answers"),
    ("robot", M, "a gap in the ticks is logged; a last line at exit says how many warnings were held back",
     "the text of a log line is the implementation's own"),
    ("robot", "Timeouts and waits", "it waits for the UAV, a plan or a tick as long as it runs",
     "no bounded test can tell forever from long; R67 checks it waits for a UAV not yet seen"),
    ("robot", "Security", "its session opens with its own certificate (`robot-<id>`, `robots-<ids>`)",
     "the suite's router has no TLS; `tests/uav_robots/test_secure.py` checks ours"),
    ("uav", E, "only a `Done` whose `tick` is after the current plan's `start_tick` counts for that plan",
     "the camera decides either way, U14 and U26: a stale `Done` only changes how long the UAV waits before it looks"),
    ("uav", W, "an answer from `world/camera` within 30 s and from `world/record` within 10 s",
     "the suite's world is ours and answers both; U29 checks the same bound on `world/info`"),
    ("uav", W, "robots still coming up are waited for at most 120 s in all; after an abort the landing 60 s",
     "they take minutes; U30 checks the 30 s without a robot coming up, U11 and the aborts that it lands"),
    ("uav", F, "how often it takes monitoring images (`--monitor-every`, automatically at most 20 % of the time)",
     "the UAV's own choice; U36 checks that each image shows a settled floor"),
    ("uav", K, "`uav/frame` carries only the newest image when images come faster than they are encoded",
     "a subscriber cannot tell a skipped image from a lost put"),
)


def rules(side: str | None = None) -> list[Rule]:
    return [r for r in RULES if side is None or r.side == side]


def since_of_test(side: str, test: str) -> int:
    """The protocol version a test needs: the newest of the rules it checks (1 for a test no rule names).

    A robot that states an older version in its `PlanAck` is not held to the rules that came after it,
    so a test that checks one of them is skipped for it; each rule has a test of its own version."""
    return max((r.since for r in rules(side) if test in r.tests), default=1)


def newer_rules(side: str, version: int) -> list[Rule]:
    """The rules of `side` that an implementation keeping protocol `version` is not held to."""
    return [r for r in rules(side) if r.since > version]


def rule(rule_id: str) -> Rule:
    for r in RULES:
        if r.id == rule_id:
            return r
    raise KeyError(f"no rule {rule_id!r}: the ids are {', '.join(r.id for r in RULES)}")


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown() -> str:
    """docs/conformance-rules.md."""
    out = ["# Conformance rules",
           "",
           "Every rule of [protocol.md](protocol.md) that a robot (R) or a UAV (U) must keep, the section it comes",
           "from, the conformance tests that check it (in `conformance/test_robot_*.py` and",
           "`conformance/test_uav_*.py`), and the mutant that proves they do: a copy of our own robot or",
           "UAV with that one rule broken (`python -m conformance.mutants robot|uav --break ID ...`), which the",
           "listed tests must fail (`tests/conformance/test_conformance_mutants.py` runs them all in CI). *Since* is the",
           "protocol version that introduced the rule: a robot whose `PlanAck` states an older `protocol` (none",
           "stated: 1) is not held to it, and the suite says so (docs/protocol.md, Versioning).",
           "",
           "Generated from `conformance/rules.py` (`python -m conformance.rules --write`); "
           "`uav-robots conformance --list-rules` prints it.",
           ""]
    for side, title in (("robot", "Robots"), ("uav", "UAVs")):
        out += [f"## {title}", "", "| id | since | section | rule | tests | mutant |", "|---|---|---|---|---|---|"]
        for r in rules(side):
            tests = "<br>".join(f"`{t}`" for t in r.tests)
            out.append(f"| {r.id} | {r.since} | {r.section} | {_cell(r.text)} | {tests} | {_cell(r.mutant)} |")
        out.append("")
        unchecked = [u for u in UNCHECKED if u[0] == side]
        if unchecked:
            out += ["Not checked, and why:", ""]
            out += [f"- {section}: {what} ({why})" for _side, section, what, why in unchecked]
            out.append("")
    return "\n".join(out)


def text_table(side: str | None = None) -> str:
    """The table for a terminal."""
    lines = []
    for r in rules(side):
        lines.append(f"{r.id:4} [{r.section}; since protocol {r.since}] {r.text}")
        lines.append(f"     tests: {', '.join(r.tests)}; mutant: {r.mutant}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m conformance.rules", description=__doc__.splitlines()[0])
    p.add_argument("--write", action="store_true", help=f"write {DOC.name}")
    p.add_argument("--check", action="store_true", help=f"exit 1 if {DOC.name} is not current")
    args = p.parse_args(argv)
    if args.write:
        DOC.write_text(markdown())
        return 0
    if args.check:
        current = DOC.exists() and DOC.read_text() == markdown()
        if not current:
            print(f"error: {DOC.name} is not current: run python -m conformance.rules --write", file=sys.stderr)
        return 0 if current else 1
    print(text_table())
    return 0


if __name__ == "__main__":
    sys.exit(main())
