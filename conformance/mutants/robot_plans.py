"""Robot mutants of taking plans: what a robot refuses and acknowledges, where a plan starts (docs/protocol.md, Plans
and ticks)."""
from __future__ import annotations

from protocol.errors import ProtocolError
from protocol.messages import PROTOCOL_VERSION, Done, Plan, PlanAck
from protocol.codec import decode

from .patching import Patch, put_if, replace, setattr_


def patches() -> dict[str, Patch]:
    """The mutants by rule id. The real methods are taken now, before any patch: each mutant builds on them."""
    from robot_agents import robot
    from robot_agents.agent import RobotPool
    from robot_agents.robot import RobotMachine

    pool_put, pool_on_plan = RobotPool._put, RobotPool._on_plan
    on_plan, problem_of = RobotMachine.on_plan, robot.plan_problem

    def problem_without(fragment: str):
        def check(plan, rid, connectivity):
            problem = problem_of(plan, rid, connectivity)
            return "" if fragment in problem else problem
        return check

    def accept_empty(self, plan):
        return self._ack(plan.plan_id, True, "") if not plan.path else on_plan(self, plan)

    def no_start_check(self, plan):
        cell = self.cell
        if plan.path and not plan.start_tick and cell is not None:
            self.cell = tuple(plan.path[0])
        ack = on_plan(self, plan)
        if not plan.start_tick and cell is not None:
            self.cell = cell   # it goes on from where it really is
        return ack

    def once_per_id(self, rid, payload):
        try:
            pid = decode(payload, Plan).plan_id
        except ProtocolError:
            pid = None
        seen = self.__dict__.setdefault("_mutant_seen", set())
        if pid in seen:
            return
        seen.add(pid)
        pool_on_plan(self, rid, payload)

    def take_same_id(self, plan):
        if self.plan is not None and plan.plan_id == self.plan.plan_id and plan.path != self.plan.path:
            self.plan = replace(self.plan, plan_id="")
        return on_plan(self, plan)

    def past_ok(self, plan):
        last = self.last_tick
        self.last_tick = 0
        try:
            return on_plan(self, plan)
        finally:
            self.last_tick = last

    def repair_as_plain(self, plan):
        return on_plan(self, replace(plan, start_tick=0))

    def from_tick_0(self, plan):
        ack = on_plan(self, plan)
        if ack.ok and not plan.start_tick:
            self.base = 0
        return ack

    def first_start_known(self, plan):
        ack = on_plan(self, plan)
        if ack.ok and self.cell is None:
            self.cell = tuple(plan.path[0])
        return ack

    def remember_ids(self, plan):
        held = self.__dict__.setdefault("_mutant_held", set())
        if plan.plan_id in held and (self.plan is None or plan.plan_id != self.plan.plan_id):
            return self._ack(plan.plan_id, False, f"plan id {plan.plan_id} was held before")
        ack = on_plan(self, plan)
        if ack.ok:
            held.add(plan.plan_id)
        return ack

    def done_at_ack(self, rid, payload):
        pool_on_plan(self, rid, payload)
        m = self.machines[rid]
        if m.plan is not None and len(m.plan.path) == 1 and m.done_sent_for != m.plan.plan_id:
            m.done_sent_for = m.plan.plan_id
            pool_put(self, rid, self.keys.done(rid), Done(robot=rid, tick=m.seen_tick, cell=tuple(m.plan.goal)))

    def done_again_when_resent(self, plan):
        if self.plan is not None and plan.plan_id == self.plan.plan_id:
            self.done_sent_for = ""
        return on_plan(self, plan)

    def no_move_when_resent(self, rid, payload):
        m, ahead = self.machines[rid], self.ahead
        try:
            resent = m.plan is not None and decode(payload, Plan).plan_id == m.plan.plan_id
        except ProtocolError:
            resent = False
        self.ahead = ahead and not resent
        try:
            pool_on_plan(self, rid, payload)
        finally:
            self.ahead = ahead

    return {
        "R4": setattr_(RobotPool, "_put", put_if(pool_put, lambda m: not (isinstance(m, PlanAck) and m.ok))),
        "R5": setattr_(robot, "plan_problem", lambda plan, rid, c: problem_of(plan, plan.robot, c)),
        "R6": setattr_(RobotMachine, "on_plan", accept_empty),
        "R7": setattr_(robot, "plan_problem", problem_without("connected move")),
        "R8": setattr_(robot, "plan_problem", problem_without("not at the goal")),
        "R9": setattr_(RobotMachine, "on_plan", no_start_check),
        "R10": setattr_(robot, "plan_problem", lambda plan, rid, c: problem_of(replace(plan, connectivity=0), rid, c)),
        "R11": setattr_(RobotPool, "_on_plan", once_per_id),
        "R12": setattr_(RobotMachine, "on_plan", take_same_id),
        "R13": setattr_(RobotMachine, "_ack", lambda self, pid, ok, error: PlanAck(
            robot=self.robot_id, plan_id=pid, ok=ok, error="" if not ok else error, protocol=PROTOCOL_VERSION)),
        "R15": setattr_(RobotMachine, "on_plan", past_ok),
        "R16": setattr_(RobotMachine, "on_plan", repair_as_plain),
        "R48": setattr_(RobotMachine, "on_plan", from_tick_0),
        "R50": setattr_(RobotMachine, "on_plan", first_start_known),
        "R51": setattr_(RobotMachine, "on_plan", remember_ids),
        "R57": setattr_(RobotPool, "_on_plan", done_at_ack),
        "R59": setattr_(RobotMachine, "on_plan", done_again_when_resent),
        "R63": setattr_(RobotPool, "_on_plan", no_move_when_resent),
    }
