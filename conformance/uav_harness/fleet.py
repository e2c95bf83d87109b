"""The fake fleet: robots in the suite's process that answer a UAV as the contract says, or break it on purpose."""
from __future__ import annotations

import dataclasses
import queue
import threading
import time
from typing import Any, Callable

from protocol.config import client_config
from protocol.errors import MissionError
from protocol.grid import Cell
from protocol.keys import Keys
from protocol.messages import (PROTOCOL_VERSION, Done, Message, MoveBatch, MoveBatchResult, Plan, PlanAck, RobotState,
                               Tick)
from protocol.codec import decode, encode
from protocol.transport import ZenohTransport

from ..waiter import Waiter
from .arrivals import Arrivals
from .fleet_state import FakeRobot, Observed
from .misbehaviour import Misbehaving, Misbehaviour, junk
from .options import FIRST_ACK_DELAY_S, FUTURE_DELAY_S, LOST_SETTLE_S, MOVE_TIMEOUT_S, MUST_DROP, RTL_HOLD_S, RTL_SEEN_S
from .plans import plan_problem


class FakeFleet(Arrivals, Misbehaving, Waiter):
    """Robots in this process, on one client session: they answer as the contract says and watch the UAV."""

    def __init__(self, endpoint: str, keys: Keys, truth: Any, behaviour: Misbehaviour, connectivity: int = 4,
                 rtl: Callable[[], float | None] | None = None) -> None:
        Waiter.__init__(self)
        self.keys, self.truth, self.behaviour, self.connectivity = keys, truth, behaviour, connectivity
        self.robots = {rid: FakeRobot(rid, tuple(cell)) for rid, cell in sorted(truth.starts.items())}
        self.log = Observed()
        self.seen_tick = 0     # the highest tick the worker has executed
        self._rtl = rtl
        self._jobs: queue.Queue = queue.Queue()
        self.transport = ZenohTransport(client_config([endpoint]), "conformance robots")
        try:
            t, k = self.transport, keys
            # Subscriptions first, tokens last: in-band readiness, as a real robot does it.
            self._handles = [
                t.subscribe(f"{k.prefix}/robot/*/plan", self._on_plan),
                t.subscribe(k.tick, self._on_tick),
                t.subscribe(k.mission_end, self._on_end),
                t.subscribe(k.mission_status, self._on_status),
                t.subscribe(k.mission_event, self._on_event),
                t.subscribe(k.uav_pose, self._on_pose),
                t.subscribe(k.uav_frame, self._on_frame),
                t.watch_alive(k.alive_uav, self._on_uav),
            ]
            self._worker = threading.Thread(target=self._work, name="conformance-robots", daemon=True)
            self._worker.start()
            for rid in self.robots:
                if rid not in behaviour.late and rid not in behaviour.absent:
                    self.join(rid)
        except BaseException:
            self.transport.close()
            raise

    # ------------------------------------------------------------ control
    def join(self, rid: int) -> None:
        """Declare robot `rid`'s liveliness token (a late robot comes up)."""
        with self.cv:
            robot = self.robots[rid]
            if robot.token is None and not robot.gone:
                robot.token = self.transport.announce(self.keys.alive_robot(rid))
                self.log.joined[rid] = time.monotonic()
            self.cv.notify_all()

    def dispatching(self) -> bool:
        """The UAV has said it is about to send plans (status phase), or has sent one."""
        with self.cv:
            return bool(self.log.plans) or any(s.phase == "dispatch" for _, s in self.log.statuses)

    def close(self) -> None:
        self._jobs.put(None)
        self._worker.join(MOVE_TIMEOUT_S + RTL_SEEN_S + RTL_HOLD_S + 1)
        for h in self._handles:
            h.close()
        with self.cv:
            for robot in self.robots.values():
                if robot.token is not None:
                    robot.token.close()
                    robot.token = None
        self.transport.close()

    # ------------------------------------------------------------ the robots' work (one thread, in order)
    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            try:
                if job[0] == "plan":
                    self._plan(job[1], job[2])
                elif job[0] == "tick":
                    self._tick(job[1])
                else:
                    self._end()
            except Exception as exc:  # noqa: BLE001 - the suite reports it; the fleet keeps answering
                with self.cv:
                    self.log.harness.append(f"{job[0]}: {type(exc).__name__}: {exc}")
                    self.cv.notify_all()

    def _fault(self, kind: str, rid: int, tick: int) -> None:
        with self.cv:
            self.log.faults.append((kind, rid, tick, time.monotonic()))
            self.cv.notify_all()

    def _put(self, robot: FakeRobot, key: str, msg: Message) -> None:
        robot.seq += 1
        self.transport.put(key, encode(dataclasses.replace(msg, seq=robot.seq)))

    def _other(self, rid: int) -> int | None:
        others = [r for r in self.robots if r != rid]
        return others[0] if others else None

    def _plan(self, rid: int, plan: Plan) -> None:
        robot = self.robots[rid]
        with self.cv:
            held = robot.plan
        if held is not None and held.plan_id == plan.plan_id:
            same = plan.path == held.path and tuple(plan.goal) == tuple(held.goal)
            problem = "" if same else f"plan {plan.plan_id} was resent with another path"
        else:
            # A repair (start_tick > 0) starts where the UAV's camera saw the robot: the world's
            # cell, which is where this robot stands (it never slips).
            problem = plan_problem(plan, rid, robot.cell, self.truth, self.connectivity)
        if problem:
            self._violation("bad-plan", f"robot {rid}, plan {plan.plan_id}: {problem}")
        ok = not problem and rid not in self.behaviour.refuse
        error = problem or ("" if ok else "refused on purpose by the conformance suite")
        if rid in self.behaviour.garbage:
            other = self._other(rid)
            fake = PlanAck(robot=rid, plan_id=plan.plan_id, ok=False, error=MUST_DROP)
            for payload in junk(fake, dataclasses.replace(fake, robot=other) if other is not None else None):
                self.transport.put(self.keys.ack(rid), payload)
        ack = PlanAck(robot=rid, plan_id=plan.plan_id, ok=ok, error=error, protocol=PROTOCOL_VERSION)
        if not self.log.acks:
            time.sleep(FIRST_ACK_DELAY_S)
        with self.cv:
            if ok and (held is None or held.plan_id != plan.plan_id):
                robot.plan, robot.base, robot.done_for = plan, plan.start_tick or self.seen_tick, ""
            robot.acked[plan.plan_id] = ok
            self.log.acks.append((time.monotonic(), ack))
        self._put(robot, self.keys.ack(rid), ack)

    def _target(self, robot: FakeRobot, tick: Tick) -> Cell:
        plan = robot.plan
        if plan is None or plan.plan_id != tick.plan_id:
            if plan is not None and tick.plan_id in robot.sent and tick.plan_id != robot.ignored_repair:
                self._violation("tick-plan-id", f"Tick {tick.k} names plan {tick.plan_id}, robot {robot.rid} "
                                                f"holds {plan.plan_id}")
            return robot.cell  # the contract: a tick for another plan (or none) means stay
        i = tick.k - robot.base
        return tuple(plan.path[max(0, min(i, len(plan.path) - 1))])

    def _tick(self, tick: Tick) -> None:
        if tick.k <= self.seen_tick:
            return  # a resent or late tick: already executed
        k, b = tick.k, self.behaviour
        vanished = [self.robots[r] for r, at in b.vanish_at.items() if at == k and r in self.robots]
        for robot in vanished:   # killed as the tick arrived: it asks and reports nothing more
            self._vanish(robot, "vanished", k)
        if vanished:
            time.sleep(LOST_SETTLE_S)   # the others are mid-tick when the UAV hears of it
        with self.cv:
            for rid, (first, ticks) in b.stall.items():
                robot = self.robots.get(rid)
                if robot is not None and k >= first and not self.log.fault("stall", rid) and self._calm(k):
                    robot.frozen = ticks
                    self.log.faults.append(("stall", rid, k, time.monotonic()))
            asking = [r for r in self.robots.values() if self._asks(r, k)]
            targets = {r.rid: self._target(r, tick) for r in asking}
            purpose = {}
            for r in asking:
                why = self._stays_on_purpose(r, k, targets)
                if why:
                    purpose[r.rid] = why
                    targets[r.rid] = r.cell
            self._make_way(targets)
            moves = [(rid, self.robots[rid].cell, targets[rid]) for rid in sorted(targets)]
            for r in self.robots.values():
                r.frozen = max(0, r.frozen - 1)   # a frozen robot sits this tick out
            for rid, why in purpose.items():
                if why != "stuck" or not self.log.fault("stuck", rid):
                    self.log.faults.append((why, rid, k, time.monotonic()))
        results = []
        if moves:
            # All robots' moves in one query: the world judges a tick once every robot has asked.
            replies = self.transport.request(self.keys.move, encode(MoveBatch(tick=k, moves=moves)), MOVE_TIMEOUT_S)
            if not replies:
                raise MissionError(f"the world did not answer the moves of tick {k}")
            results = decode(replies[0], MoveBatchResult).results
        self.seen_tick = k
        for rid in b.liar & set(self.robots):
            self._lie(self.robots[rid], tick)
        with self.cv:
            for rid, accepted, cell, reason in results:
                self.robots[rid].cell = tuple(cell)
        # A robot lost at this tick reports it, then its token vanishes; the others report once the UAV
        # has had time to hear of it: a UAV that watches liveliness holds the fleet, one that does not
        # finds its barrier complete.
        lost = [rid for rid, *_ in results if b.lost_at.get(rid) == k]
        order = sorted(results, key=lambda res: res[0] not in lost)
        if b.rtl_at == k and self._rtl is not None:
            seen = self._rtl()
            if seen is None:
                raise MissionError("the vehicle did not switch to RTL when the ground station commanded it")
            self._fault("rtl", -1, k)
            time.sleep(RTL_HOLD_S)   # a UAV that watches its vehicle ends the mission before it could tick on
        delayed = []
        for rid, accepted, cell, reason in order:
            robot = self.robots[rid]
            if k >= b.silent_from.get(rid, k + 1):
                continue  # executes the tick but stops reporting: the UAV's barrier must hold
            if rid in b.garbage and k == 3:
                delayed.append((robot, accepted, reason))   # it put a state for this tick before the tick
                continue
            self._report(robot, tick, accepted, reason, "error" if b.error_at.get(rid) == k else "")
            if rid in lost:
                self._vanish(robot, "lost", k)
                if rid == lost[-1]:
                    time.sleep(LOST_SETTLE_S)
        if delayed:
            time.sleep(FUTURE_DELAY_S)
            for robot, accepted, reason in delayed:
                self._report(robot, tick, accepted, reason, "")

    def _report(self, robot: FakeRobot, tick: Tick, accepted: bool, reason: str, error: str) -> None:
        plan, rid, k = robot.plan, robot.rid, tick.k
        arrived = (plan is not None and plan.plan_id == tick.plan_id and k - robot.base >= len(plan.path) - 1
                   and robot.cell == tuple(plan.goal))
        status = "error" if error else ("done" if arrived else "stepping")
        state = RobotState(robot=rid, tick=k, cell=robot.cell, status=status, plan_id=plan.plan_id if plan else "",
                           error="its drive failed (the conformance suite)" if error else ("" if accepted else reason))
        garbage = rid in self.behaviour.garbage and k <= 3
        if garbage:
            self._garbage(robot, state)
        if garbage and k == 2:
            self._future(robot, state, tick)   # before its state of 2: the UAV cannot have put Tick 3 yet
        with self.cv:
            robot.reported.add(k)  # before the put: the UAV cannot legitimately have it earlier
        self._put(robot, self.keys.state(rid), state)
        if garbage and robot.last_state is not None:
            self._put(robot, self.keys.state(rid), robot.last_state)  # the previous tick's state, resent late
        robot.last_state = state
        if error:
            return
        if arrived and robot.done_for != plan.plan_id:
            done = Done(robot=rid, tick=k, cell=robot.cell)
            with self.cv:
                robot.done_for = plan.plan_id
                if rid in self.behaviour.mute:
                    return   # it has arrived, and says nothing: the camera must see it
                self.log.dones.append((time.monotonic(), done))
            self._put(robot, self.keys.done(rid), done)
            if rid in self.behaviour.garbage:
                self._put(robot, self.keys.done(rid), done)  # a resent Done

    def _end(self) -> None:
        # Robots leave on MissionEnd, withdrawing their tokens.
        with self.cv:
            for robot in self.robots.values():
                if robot.token is not None:
                    robot.token.close()
                    robot.token = None
