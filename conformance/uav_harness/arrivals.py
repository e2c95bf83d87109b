"""The fake fleet's ears: what the UAV puts, checked the moment it arrives, and queued for the robots' work."""
from __future__ import annotations

import queue
import threading
import time
from typing import Any

from protocol.errors import ProtocolError
from protocol.keys import robot_id_from_key
from protocol.messages import CameraFrame, MissionEnd, MissionEvent, MissionStatus, Plan, Tick, VehiclePose
from protocol.codec import decode

from .fleet_state import FakeRobot, Observed
from .misbehaviour import Misbehaviour


class Arrivals:
    """The UAV's messages as they come, on the transport's threads: a mixin of `FakeFleet`.

    Only here can some rules be checked (was this robot's token up when its plan came? had every robot
    reported the previous tick?); the robots' answers are left to the fleet's worker, in order.
    """
    cv: threading.Condition
    behaviour: Misbehaviour
    robots: dict[int, FakeRobot]
    log: Observed
    _jobs: queue.Queue

    def _violation(self, kind: str, text: str) -> None:
        with self.cv:
            self.log.violations.append((kind, text))
            self.cv.notify_all()

    def _decode(self, key: str, payload: bytes, cls: type) -> Any:
        try:
            msg = decode(payload, cls)
        except ProtocolError as exc:
            self._violation("malformed", f"the UAV put an unreadable message on {key}: {exc}")
            return None
        if cls not in (CameraFrame, VehiclePose):   # an image keeps its number, the pose stream counts its own
            with self.cv:
                self.log.seqs.append((cls.__name__, msg.seq))
        return msg

    def _on_plan(self, key: str, payload: bytes) -> None:
        plan = self._decode(key, payload, Plan)
        rid = robot_id_from_key(key)
        if plan is None:
            return
        with self.cv:
            robot = self.robots.get(rid) if rid is not None else None
            up = robot is not None and robot.token is not None
            self.log.plans.append((time.monotonic(), rid if rid is not None else -1, plan, up))
            if robot is not None:
                robot.sent.add(plan.plan_id)
            ended = bool(self.log.ends)
            self.cv.notify_all()
        if ended:
            self._violation("after-end", f"plan {plan.plan_id} to robot {rid} after MissionEnd")
        if robot is None:
            self._violation("plan-unknown", f"plan {plan.plan_id} on {key}: no such robot in the world")
        elif not up:
            # A real robot is not listening yet (or any more): the plan is lost.
            self._violation("plan-before-token", f"plan {plan.plan_id} sent to robot {rid} while its token was down")
        elif rid in self.behaviour.deaf and self._lost_on_the_way(rid, plan):
            return  # the first puts of its first plan never reach it: the UAV must put it again
        elif rid in self.behaviour.deaf_repair and plan.start_tick > 0 and robot.ignored_repair in ("", plan.plan_id):
            if not robot.ignored_repair:
                robot.ignored_repair = plan.plan_id
                self._fault("deaf-repair", rid, plan.start_tick)
            return  # its first repair never reaches it, however often it is put
        else:
            self._jobs.put(("plan", rid, plan))

    def _lost_on_the_way(self, rid: int, plan: Plan) -> bool:
        with self.cv:
            mine = [p.plan_id for _, r, p, up in self.log.plans if r == rid and up]
        return mine[0] == plan.plan_id and len(mine) <= self.behaviour.deaf_puts

    def _on_tick(self, key: str, payload: bytes) -> None:
        tick = self._decode(key, payload, Tick)
        if tick is None:
            return
        with self.cv:
            prev = self.log.ticks[-1][1].k if self.log.ticks else 0
            prev_plan = self.log.ticks[-1][1].plan_id if self.log.ticks else None
            self.log.ticks.append((time.monotonic(), tick))
            problems = []
            if tick.k != prev + 1:
                problems.append(("tick-order", f"Tick {tick.k} followed Tick {prev}"))
            if tick.plan_id != prev_plan:
                # The first tick of a plan: every robot it was sent to has taken it (a replan leaves out
                # the robots the UAV gave up on; they get no plan and stay).
                unacked = [r.rid for r in self.robots.values()
                           if (prev == 0 or tick.plan_id in r.sent) and not r.acked.get(tick.plan_id)
                           and not r.ignored_repair == tick.plan_id]
                if unacked:
                    problems.append(("tick-before-ack", f"Tick {tick.k} (plan {tick.plan_id}) before robots "
                                                        f"{unacked} acknowledged that plan"))
            else:
                silent = [r.rid for r in self.robots.values() if r.acked.get(tick.plan_id) and prev not in r.reported]
                if silent:
                    problems.append(("barrier", f"Tick {tick.k} before robots {silent} reported tick {prev}"))
            if self.log.ends:
                problems.append(("after-end", f"Tick {tick.k} after MissionEnd"))
            self.log.violations += problems
            self.cv.notify_all()
        self._jobs.put(("tick", tick))

    def _on_end(self, key: str, payload: bytes) -> None:
        end = self._decode(key, payload, MissionEnd)
        if end is not None:
            with self.cv:
                self.log.ends.append((time.monotonic(), end))
                self.cv.notify_all()
            self._jobs.put(("end",))

    def _keep(self, into: list, key: str, payload: bytes, cls: type) -> None:
        msg = self._decode(key, payload, cls)
        if msg is not None:
            with self.cv:
                into.append((time.monotonic(), msg))
                self.cv.notify_all()

    def _on_status(self, key: str, payload: bytes) -> None:
        self._keep(self.log.statuses, key, payload, MissionStatus)

    def _on_event(self, key: str, payload: bytes) -> None:
        self._keep(self.log.events, key, payload, MissionEvent)

    def _on_pose(self, key: str, payload: bytes) -> None:
        self._keep(self.log.poses, key, payload, VehiclePose)

    def _on_frame(self, key: str, payload: bytes) -> None:
        self._keep(self.log.frames, key, payload, CameraFrame)

    def _on_uav(self, _key: str, alive: bool) -> None:
        with self.cv:
            self.log.uav_alive.append((time.monotonic(), alive))
            self.cv.notify_all()
