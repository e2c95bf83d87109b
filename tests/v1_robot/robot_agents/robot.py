"""One robot's state machine: idle -> ready (has a plan) -> stepping -> done.

Pure: it never touches the network. The agent feeds it plans, ticks and the
world's answers and publishes what it returns. The robot only ever moves to
the cell its plan names for the tick, and only believes the world about where
it stands: a refused move leaves it where the world says it is.

Ticks are mission time: global, 1-based and strictly increasing. A plan
accepted when the highest tick seen so far is `b` puts path[i] at tick b + i
(b = 0 for the first plan: path[k] is the cell at tick k).
"""
from __future__ import annotations

from dataclasses import dataclass

from protocol.errors import ProtocolError
from protocol.grid import Cell
from protocol.messages import Done, MoveResult, Plan, PlanAck, RobotState, Tick

IDLE, READY, STEPPING, DONE, ERROR = "idle", "ready", "stepping", "done", "error"


def plan_problem(plan: Plan, robot_id: int, connectivity: int) -> str:
    """Why `plan` cannot be executed by this robot ('' if it can)."""
    if plan.robot != robot_id:
        return f"plan is for robot {plan.robot}, this is robot {robot_id}"
    if not plan.plan_id:
        return "plan has an empty plan_id"
    if not plan.path:
        return "plan has an empty path"
    for i, c in enumerate(plan.path):
        if c[0] < 0 or c[1] < 0:
            return f"path cell {i} {c} has a negative coordinate"
    for i in range(1, len(plan.path)):
        (x0, y0), (x1, y1) = plan.path[i - 1], plan.path[i]
        dx, dy = abs(x1 - x0), abs(y1 - y0)
        if (dx + dy > 1) if connectivity == 4 else (max(dx, dy) > 1):
            return f"path step {i} {plan.path[i - 1]} -> {plan.path[i]} is not a {connectivity}-connected move"
    if tuple(plan.path[-1]) != tuple(plan.goal):
        return f"path ends at {plan.path[-1]}, not at the goal {plan.goal}"
    return ""


@dataclass(frozen=True)
class Step:
    """The move a robot asks the world for at one tick."""
    tick: int
    frm: Cell
    to: Cell


class RobotMachine:
    def __init__(self, robot_id: int, connectivity: int = 4) -> None:
        self.robot_id = robot_id
        self.connectivity = connectivity
        self.state = IDLE
        self.plan: Plan | None = None
        self.base = 0                 # path[i] is the cell at tick base + i
        self.cell: Cell | None = None  # where the world last said this robot is
        self.last_tick = 0            # the last tick executed
        self.seen_tick = 0            # the highest tick heard of (executed or not)
        self.done_sent_for = ""       # plan_id whose Done was published

    # ------------------------------------------------------------- plans
    def on_plan(self, plan: Plan) -> PlanAck:
        pid = plan.plan_id
        if self.plan is not None and pid == self.plan.plan_id and plan.robot == self.robot_id:
            same = plan.path == self.plan.path and tuple(plan.goal) == tuple(self.plan.goal)
            # A resent plan is acknowledged again; a different plan under the same id is a mistake.
            return self._ack(pid, same, "" if same else f"plan {pid} was already received with another path")
        problem = plan_problem(plan, self.robot_id, self.connectivity)
        if problem:
            return self._ack(pid, False, problem)
        start = (int(plan.path[0][0]), int(plan.path[0][1]))
        if self.cell is not None and start != self.cell:
            return self._ack(pid, False, f"plan starts at {start} but robot {self.robot_id} is at {self.cell}")
        if self.state == STEPPING and self.cell is None:
            return self._ack(pid, False, f"busy stepping plan {self.plan.plan_id if self.plan else ''}")
        # While stepping, a new plan that starts where the robot stands is a replan from here.
        self.plan = plan
        self.base = self.seen_tick
        self.state = READY
        self.done_sent_for = ""
        return self._ack(pid, True, "")

    def _ack(self, plan_id: str, ok: bool, error: str) -> PlanAck:
        return PlanAck(robot=self.robot_id, plan_id=plan_id, ok=ok, error=error)

    # ------------------------------------------------------------- ticks
    def classify(self, tick: Tick) -> str:
        """'run', 'old' (duplicate or late: ignore) or 'gap' (ticks were missed; run anyway)."""
        if tick.k <= self.last_tick:
            return "old"
        gap = tick.k > self.last_tick + 1
        self.seen_tick = max(self.seen_tick, tick.k)
        return "gap" if gap else "run"

    def target(self, tick: int, plan_id: str | None = None) -> Step | None:
        """The move to request at `tick`; None when the robot has no plan and no known cell.

        A tick for another plan than the one held means this robot missed a
        plan: it stays where it is, which is always safe and still blocks its cell.
        """
        if self.plan is None:
            return None if self.cell is None else Step(tick, self.cell, self.cell)
        path = self.plan.path
        i = tick - self.base
        if i < 1:
            raise ProtocolError(f"tick {tick} is not after the plan's start tick {self.base}")
        frm = self.cell if self.cell is not None else tuple(path[min(i - 1, len(path) - 1)])
        if plan_id is not None and plan_id != self.plan.plan_id:
            return Step(tick, frm, frm)
        if self.state == READY:
            self.state = STEPPING
        return Step(tick, frm, tuple(path[min(i, len(path) - 1)]))

    def on_move_result(self, result: MoveResult, plan_id: str | None = None) -> tuple[RobotState, Done | None]:
        """The world's answer -> the state to publish, and a Done the first time the goal is reached."""
        if result.robot != self.robot_id:
            raise ProtocolError(f"move result for robot {result.robot} given to robot {self.robot_id}")
        self.cell = (int(result.cell[0]), int(result.cell[1]))
        self.last_tick = max(self.last_tick, result.tick)
        self.seen_tick = max(self.seen_tick, result.tick)
        done = None
        if self.plan is not None and (plan_id is None or plan_id == self.plan.plan_id):
            over = result.tick - self.base >= len(self.plan.path) - 1
            if over and self.cell == tuple(self.plan.goal):
                self.state = DONE
                if self.done_sent_for != self.plan.plan_id:
                    self.done_sent_for = self.plan.plan_id
                    done = Done(robot=self.robot_id, tick=result.tick, cell=self.cell)
            elif self.state == DONE:
                self.state = STEPPING  # pushed off its goal? keep trying to get back
        return self.status(result.tick, "" if result.accepted else result.reason), done

    def on_no_result(self, step: Step, reason: str) -> RobotState:
        """The world did not answer: report an error from where the robot last knew it was."""
        self.last_tick = max(self.last_tick, step.tick)
        if self.cell is None:
            self.cell = step.frm
        return RobotState(robot=self.robot_id, tick=step.tick, cell=self.cell, status=ERROR,
                          plan_id=self.plan.plan_id if self.plan else "", error=reason)

    def status(self, tick: int, note: str = "") -> RobotState:
        cell = self.cell if self.cell is not None else (
            tuple(self.plan.path[0]) if self.plan is not None else (-1, -1))
        return RobotState(robot=self.robot_id, tick=tick, cell=cell, status=self.state,
                          plan_id=self.plan.plan_id if self.plan else "", error=note)
