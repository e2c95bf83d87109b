"""The physics of robot steps: which moves of one tick the floor allows.

`MoveJudge` is the world's referee. All moves of a tick happen at once, so a
robot may follow another into the cell it leaves, but two robots may never end
in one cell, swap cells, or (8-connected) cross diagonals. A refused robot
stays where it is, which can block a robot that wanted to follow it: refusals
are propagated until nothing changes. Pure: no clock, no network.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from protocol.errors import UavRobotsError
from protocol.grid import Cell, on_grid
from protocol.messages import MoveResult

from .traffic import Traffic


@dataclass(frozen=True)
class Refusal:
    tick: int
    robot: int
    frm: Cell | None
    to: Cell | None
    reason: str
    collision: bool  # False for protocol slips (late tick, unknown robot, missing request)

    def as_dict(self) -> dict[str, Any]:
        return {"tick": self.tick, "robot": self.robot,
                "from": list(self.frm) if self.frm is not None else None,
                "to": list(self.to) if self.to is not None else None,
                "reason": self.reason, "collision": self.collision}


def _safety_stops(why: dict[int, str], blockers: dict[int, set[int]], astray: set[int]) -> dict[int, int]:
    """The refused robots stopped by a robot `astray` (one that did not move as its plan said for a
    reason outside the plan: it slipped unseen and asked from the wrong cell, or it asked nothing, dead
    or stalled), directly or through robots stopped so in turn: robot -> the robot astray. No plan put
    them in conflict: the robot's own safety stops it, which the record keeps apart from collisions."""
    cause = {r: r for r in astray}
    changed = True
    while changed:
        changed = False
        for r in why:
            if r not in cause:
                hit = sorted(b for b in blockers.get(r, ()) if b in cause)
                if hit:
                    cause[r] = cause[hit[0]]
                    changed = True
    return {r: c for r, c in cause.items() if r not in astray}


@dataclass
class MoveJudge:
    free: np.ndarray
    positions: dict[int, Cell]
    connectivity: int = 4
    tick: int = 0                                   # the last resolved tick
    record: dict[int, list[Cell]] = field(default_factory=dict)
    collisions: int = 0
    safety_stops: int = 0         # moves refused because a robot that slipped unseen stood in the way
    refused: list[Refusal] = field(default_factory=list)
    skid_prob: float = 0.0        # `--fault slip:P`: a move ends elsewhere, and the robot is not told
    skid_robots: dict[int, int] = field(default_factory=dict)   # `--fault skid:R@T`: from tick T, every move of R
    seed: int = 0
    skids: list[dict[str, Any]] = field(default_factory=list)
    traffic: Traffic | None = None   # the floor's people, forklifts and pallets (traffic.py), stepped with each tick
    mover_collisions: int = 0        # robot-mover contacts, also counted in `collisions`

    def __post_init__(self) -> None:
        if self.connectivity not in (4, 8):
            raise UavRobotsError(f"connectivity must be 4 or 8, got {self.connectivity}")
        self.positions = {int(r): (int(c[0]), int(c[1])) for r, c in self.positions.items()}
        seen: dict[Cell, int] = {}
        for r, c in self.positions.items():
            if not self._on_free(c):
                raise UavRobotsError(f"robot {r} starts at {c}, which is not a free cell")
            if c in seen:
                raise UavRobotsError(f"robots {seen[c]} and {r} both start at {c}")
            seen[c] = r
        if not self.record:
            self.record = {r: [c] for r, c in self.positions.items()}
        if not 0.0 <= self.skid_prob <= 1.0:
            raise UavRobotsError(f"slip probability must be in [0, 1], got {self.skid_prob}")
        self._rng = np.random.default_rng(self.seed)

    # ----------------------------------------------------------- geometry
    def _on_free(self, c: Cell) -> bool:
        h, w = self.free.shape
        return on_grid(c[0], c[1], w, h) and bool(self.free[c[1], c[0]])

    def _step_problem(self, frm: Cell, to: Cell) -> str:
        """Why one robot alone could not make this step ('' if it could)."""
        h, w = self.free.shape
        if not on_grid(to[0], to[1], w, h):
            return f"{to} is off the {w}x{h} grid"
        if not self.free[to[1], to[0]]:
            return f"{to} is an obstacle"
        dx, dy = to[0] - frm[0], to[1] - frm[1]
        if self.connectivity == 4 and abs(dx) + abs(dy) > 1:
            return f"{frm} -> {to} is not a 4-connected step"
        if max(abs(dx), abs(dy)) > 1:
            return f"{frm} -> {to} is more than one cell"
        if dx and dy and not (self.free[frm[1], to[0]] and self.free[to[1], frm[0]]):
            return f"{frm} -> {to} cuts an obstacle's corner"
        return ""

    # ------------------------------------------------------------- a tick
    def resolve(self, tick: int, requests: Mapping[int, tuple[Cell, Cell]]) -> dict[int, MoveResult]:
        """Apply one tick's moves simultaneously; robots without a request stay.

        Returns an outcome for every requesting robot (known or not). A tick at
        or before the last resolved one changes nothing.
        """
        out: dict[int, MoveResult] = {}
        if tick <= self.tick:
            for r, (frm, to) in requests.items():
                out[r] = self.slip(tick, r, frm, to, f"tick {tick} is over (the world is at tick {self.tick})")
            return out
        for r, (frm, to) in requests.items():
            if r not in self.positions:
                out[r] = self.slip(tick, r, frm, to, f"unknown robot {r}")
        # Ticks nobody asked for are ticks where everybody stayed.
        for t in range(self.tick + 1, tick):
            for r, c in self.positions.items():
                self.record[r].append(c)

        pos = self.positions
        target: dict[int, Cell] = {}
        why: dict[int, str] = {}
        lost: set[int] = set()
        for r, (frm, to) in requests.items():
            if r not in pos:
                continue
            frm, to = (int(frm[0]), int(frm[1])), (int(to[0]), int(to[1]))
            if frm != pos[r]:
                lost.add(r)   # the robot is wrong about where it is: no motion happens, nobody is hit
                why[r] = f"robot {r} is at {pos[r]}, not at {frm}"
            elif to != frm:
                problem = self._step_problem(frm, to)
                if problem:
                    why[r] = problem
                else:
                    target[r] = to
        blockers: dict[int, set[int]] = {}
        self._settle(target, why, blockers)
        # Robots that did not move as the plan said for a reason outside it: wrong about their cell
        # (slipped unseen), or not asking at all (dead, stalled). Whoever they stop is safety-stopped.
        stopped = _safety_stops(why, blockers, lost | (set(pos) - set(requests)))

        for r, (frm, to) in requests.items():
            if r not in pos:
                continue
            if r in why:
                if r in stopped:
                    how = "slipped there unseen" if stopped[r] in lost else "did not move"
                    why[r] += f" (robot {stopped[r]} {how}: a safety stop)"
                    self.safety_stops += 1
                collision = r not in lost and r not in stopped
                self.collisions += collision
                self.refused.append(Refusal(tick, r, tuple(frm), tuple(to), why[r], collision))
                out[r] = MoveResult(r, tick, False, pos[r], why[r])
        actual = self._skid(tick, target) if self.skid_prob or self.skid_robots else target
        before = dict(pos)
        for r, to in actual.items():
            pos[r] = to
        if self.traffic is not None:
            touched = len(self.traffic.step(tick, before, pos))
            self.mover_collisions += touched
            self.collisions += touched
        for r, (frm, to) in requests.items():
            if r in pos and r not in why:
                # After a skid the robot believes it arrived: only an outside look can tell.
                out[r] = MoveResult(r, tick, True, target.get(r, pos[r]))
        for r, c in pos.items():
            self.record[r].append(c)
        self.tick = tick
        return out

    def _settle(self, target: dict[int, Cell], why: dict[int, str], blockers: dict[int, set[int]]) -> None:
        """Drop conflicting moves from `target` (reasons into `why`, the robots in the way into
        `blockers`) until the rest is consistent."""
        pos = self.positions
        changed = True
        while changed:
            changed = False
            after: dict[Cell, list[int]] = {}
            for r, c in pos.items():
                after.setdefault(target.get(r, c), []).append(r)
            for cell, rs in after.items():
                if len(rs) < 2:
                    continue
                stayer = next((r for r in rs if r not in target), None)
                for r in rs:
                    if r in target:
                        other = stayer if stayer is not None else next(o for o in rs if o != r)
                        why[r] = (f"{cell} is taken by robot {other}" if stayer is not None
                                  else f"robots {sorted(rs)} all moving into {cell}")
                        blockers.setdefault(r, set()).update([stayer] if stayer is not None else set(rs) - {r})
                        changed = True
                for r in rs:
                    target.pop(r, None)
            origin = {pos[r]: r for r in target}
            clash: dict[int, str] = {}
            for r, to in target.items():
                s = origin.get(to)
                if s is not None and s != r and target.get(s) == pos[r]:
                    clash[r] = f"swap with robot {s} between {pos[r]} and {to}"
                    blockers.setdefault(r, set()).add(s)
                frm = pos[r]
                if self.connectivity == 8 and frm[0] != to[0] and frm[1] != to[1]:
                    # The other diagonal of the same 2x2 square, travelled either way.
                    a, b = (to[0], frm[1]), (frm[0], to[1])
                    for start, end in ((a, b), (b, a)):
                        s = origin.get(start)
                        if s is not None and target.get(s) == end:
                            clash[r] = f"diagonal crossing with robot {s}"
                            blockers.setdefault(r, set()).add(s)
            for r, reason in clash.items():
                why[r] = reason
                del target[r]
                changed = True

    def _skid(self, tick: int, target: dict[int, Cell]) -> dict[int, Cell]:
        """Some moves end elsewhere: the robot stays, or lands in another free neighbour cell nobody
        else occupies after the tick. Never into a conflict: a skid that would hit someone does not happen."""
        pos = self.positions
        # Cells someone stands on now or after the tick are out: no vertex conflict, no swap.
        taken = {target.get(r, c) for r, c in pos.items()} | set(pos.values())
        if self.traffic is not None:   # nor onto a mover: its bumper stops it first
            taken |= {m.cell for m in self.traffic.on_floor()}
        actual = dict(target)
        for r, to in target.items():
            broken = tick >= self.skid_robots.get(r, tick + 1)
            if not broken and self._rng.random() >= self.skid_prob:
                continue
            frm = pos[r]
            sideways = [(frm[0] + dx, frm[1] + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))]
            options = [c for c in sideways if c != to and c not in taken and not self._step_problem(frm, c)]
            if frm not in {target.get(o, c) for o, c in pos.items() if o != r}:
                options.append(frm)   # no wheel turned: it stays, unless someone follows into its cell
            if not options:
                continue
            land = options[int(self._rng.integers(len(options)))]
            taken.discard(to)
            taken.add(land)
            actual[r] = land
            self.skids.append({"tick": tick, "robot": r, "intended": list(to), "actual": list(land)})
        return actual

    def slip(self, tick: int, robot: int, frm: Cell, to: Cell, reason: str) -> MoveResult:
        self.refused.append(Refusal(tick, robot, tuple(frm), tuple(to), reason, False))
        return MoveResult(robot, tick, False, self.positions.get(robot, tuple(frm)), reason)

    def note_missing(self, tick: int, robots: list[int], reason: str) -> None:
        """Robots that sent no request for a resolved tick (they stayed): reported, not collisions."""
        for r in robots:
            self.refused.append(Refusal(tick, r, None, None, reason, False))

    # -------------------------------------------------------------- views
    def executed(self) -> dict[str, list[Cell]]:
        return {str(r): list(cells) for r, cells in sorted(self.record.items())}

    def refused_dicts(self) -> list[dict[str, Any]]:
        return [f.as_dict() for f in self.refused]
