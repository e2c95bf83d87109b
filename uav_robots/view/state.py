"""What the live view shows, kept from the fleet's messages: robots, plans, goals, tick, phase, events, image, the
drone's pose, and the world's movers (people, forklifts, pallets) when the floor has any.

`FleetView.apply` takes one wire sample; `FleetView.delta` gives a client what changed since its last
update (robots that moved, plans that changed, events it has not seen, the image if newer, the movers if
they moved), so a browser gets per-tick deltas and a slow one simply gets fewer, larger ones.
"""
from __future__ import annotations

import base64
import json
import threading
from dataclasses import dataclass, field
from typing import Any

from protocol.codec import decode
from protocol.messages import CameraFrame, FloorMovers, VehiclePose


@dataclass
class Seen:
    """What one client has been sent."""
    robots: dict[int, tuple] = field(default_factory=dict)
    plans: int = -1
    events: int = 0
    image: int = 0
    movers: int = 0
    movers_outcome: int = 0


def movers_outcome(report: dict[str, Any]) -> dict[str, int] | None:
    """The robot-mover collisions and near misses of a mission's report (report.json's top level, written
    when the floor had movers); None when it had none, so a floor without movers shows no such counter."""
    if not report.get("movers"):
        return None
    return {"movers": report["movers"], "collisions": report.get("mover_collisions", 0),
            "near_misses": report.get("near_misses", 0)}


class FleetView:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.robots: dict[int, tuple] = {}             # id -> (x, y, status)
        self.goals: dict[int, list[int]] = {}
        self.paths: dict[int, list[list[int]]] = {}
        self.plan_version = 0
        self.tick = 0
        self.ticks = 0
        self.phase = "connecting"
        self.message = ""
        self.events: list[dict[str, Any]] = []
        self.image: str = ""                           # data: URL of the newest JPEG
        self.image_version = 0
        self.pose: dict[str, float] = {}
        self.pose_fed = False                          # the UAV sends VehiclePose: images no longer move the drone
        self.poses = 0                                 # VehiclePose messages applied
        self.end: dict[str, Any] | None = None
        self.movers: dict[int, tuple] = {}             # id -> (kind, x, y), from the newest FloorMovers
        self.movers_tick = -1
        self.movers_version = 0                        # 0: no movers heard, nothing sent (a floor as before)
        self.outcome: dict[str, int] | None = None     # the report's robot-mover counts, once known
        self.outcome_version = 0

    def apply(self, key: str, payload: bytes) -> None:
        tail = key.rsplit("/", 2)
        kind = tail[-1]
        try:
            if kind == "frame":
                f = decode(payload, CameraFrame)
                with self._lock:
                    self.image = f"data:image/{f.encoding};base64," + base64.b64encode(f.png).decode()
                    self.image_version += 1
                    if not self.pose_fed:
                        self.pose = {"east_m": f.east_m, "north_m": f.north_m, "alt_m": -f.down_m}
                return
            if kind == "pose" and tail[-2] == "uav":
                p = decode(payload, VehiclePose)
                with self._lock:
                    self.pose = {"east_m": p.east_m, "north_m": p.north_m, "alt_m": -p.down_m, "yaw_rad": p.yaw_rad,
                                 "mode": p.mode, "in_air": p.in_air}
                    self.pose_fed = True
                    self.poses += 1
                return
            if kind == "movers" and tail[-2] == "world":
                self._movers(decode(payload, FloorMovers))
                return
            body = json.loads(payload)
        except Exception:  # noqa: BLE001 - a view shows what it can read
            return
        try:
            self._fleet_message(kind, tail, body)
        except (KeyError, TypeError, ValueError, IndexError, AttributeError):
            return   # valid JSON of the wrong shape (a forged or foreign put): the view goes on

    def _fleet_message(self, kind: str, tail: list[str], body: Any) -> None:
        with self._lock:
            if kind == "state":
                self.robots[body["robot"]] = (*body["cell"], body.get("status", ""))
                self.tick = max(self.tick, body["tick"])
            elif kind == "states":   # a pool's StateBatch
                for rid, cell, status, *_ in body["states"]:
                    self.robots[rid] = (*cell, status)
                self.tick = max(self.tick, body["tick"])
            elif kind == "plan":
                rid = body["robot"]
                self.goals[rid] = body["goal"]
                self.paths[rid] = body["path"]
                self.robots.setdefault(rid, (*body["path"][0], "planned"))
                self.plan_version += 1
            elif kind == "tick":
                self.ticks = body["ticks"]
            elif kind == "status" and tail[-2] == "mission":
                self.phase, self.message = body["phase"], body.get("message", "")
                self.ticks = body.get("ticks") or self.ticks
            elif kind == "event" and tail[-2] == "mission":
                self.events.append({k: body.get(k) for k in ("tick", "time_s", "kind", "robots", "what", "action")})
            elif kind == "end" and tail[-2] == "mission":
                self.end = {"completed": body["completed"], "reason": body.get("reason", "")}

    def _movers(self, m: FloorMovers) -> None:
        """The world puts the whole floor's movers after each tick; one overtaken by a newer is dropped, and
        one that moved nobody (a parked forklift, a pallet, a pause) changes nothing a client is sent."""
        now = {mid: (kind, *cell) for mid, kind, cell in m.movers}
        with self._lock:
            if m.tick < self.movers_tick:
                return
            self.movers_tick = m.tick
            if now != self.movers or not self.movers_version:
                self.movers = now
                self.movers_version += 1

    def report(self, report: dict[str, Any]) -> None:
        """The mission's report, once written: the robot-mover collisions and near misses (the world counts
        them; nothing on the wire says them during the mission)."""
        outcome = movers_outcome(report)
        with self._lock:
            if outcome is not None and outcome != self.outcome:
                self.outcome = outcome
                self.outcome_version += 1

    def delta(self, seen: Seen) -> dict[str, Any]:
        with self._lock:
            out: dict[str, Any] = {"tick": self.tick, "ticks": self.ticks, "phase": self.phase,
                                   "message": self.message, "end": self.end, "pose": self.pose,
                                   "poses": self.poses}
            moved = {str(r): list(v) for r, v in self.robots.items() if seen.robots.get(r) != v}
            if moved:
                out["robots"] = moved
                seen.robots.update({r: v for r, v in self.robots.items()})
            if seen.plans != self.plan_version:
                out["goals"] = {str(r): g for r, g in self.goals.items()}
                out["paths"] = {str(r): p for r, p in self.paths.items()}
                seen.plans = self.plan_version
            if seen.events < len(self.events):
                out["events"] = self.events[seen.events:]
                seen.events = len(self.events)
            if seen.image != self.image_version:
                out["image"] = self.image
                seen.image = self.image_version
            # The whole set when any moved: a few tens at most, and one that leaves the floor goes too.
            if seen.movers != self.movers_version:
                out["movers"] = {str(i): list(v) for i, v in self.movers.items()}
                seen.movers = self.movers_version
            if seen.movers_outcome != self.outcome_version:
                out["movers_outcome"] = self.outcome
                seen.movers_outcome = self.outcome_version
            return out
