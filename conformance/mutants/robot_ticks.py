"""Robot mutants of executing ticks: which move is asked, of whom, when, and what is made of the answer
(docs/protocol.md, Plans and ticks)."""
from __future__ import annotations

import time

from protocol.errors import ProtocolError
from protocol.messages import MoveAhead, MoveResult, Tick
from protocol.codec import decode, encode

from .patching import Patch, replace, setattr_


def patches() -> dict[str, Patch]:
    """The mutants by rule id. The real methods are taken now, before any patch: each mutant builds on them."""
    from robot_agents import agent
    from robot_agents.agent import RobotPool
    from robot_agents.robot import DONE, RobotMachine

    pool_start, target, on_result = RobotPool.start, RobotMachine.target, RobotMachine.on_move_result

    def one_ahead(self, tick, plan_id=None):
        step = target(self, tick + 1, plan_id)
        return None if step is None else replace(step, tick=tick)

    def from_plan_cell(self, tick, plan_id=None):
        step = target(self, tick, plan_id)
        if step is None or self.plan is None:
            return step
        path = self.plan.path
        return replace(step, frm=tuple(path[max(0, min(tick - self.base - 1, len(path) - 1))]))

    def report_plan_cell(self, result, plan_id=None):
        state, done = on_result(self, result, plan_id)
        if self.plan is not None:
            path = self.plan.path
            state = replace(state, cell=tuple(path[max(0, min(result.tick - self.base, len(path) - 1))]))
        return state, done

    def done_again(self, result, plan_id=None):
        self.done_sent_for = ""
        return on_result(self, result, plan_id)

    pool_tick = RobotPool._on_tick

    def quiet_when_done(self, payload):
        if all(m.state == DONE for m in self.machines.values()):
            return
        pool_tick(self, payload)

    ask_world = RobotPool._ask_world

    def a_request_each(self, k, steps):
        out = {}
        for r, st in steps.items():
            out.update(ask_world(self, k, {r: st}))
        return out

    on_judged = RobotPool._on_judged

    def states_first(self, payload):
        held = []
        self._put_ahead = lambda k, robots: held.append((k, robots))
        try:
            on_judged(self, payload)
        finally:
            del self._put_ahead
        time.sleep(0.2)   # past the UAV's barrier, as a busy robot would be
        for k, robots in held:
            self._put_ahead(k, robots)

    def one_move_ahead(self, k, robots):
        moves, plan_id = [], None
        for r in robots:
            m = self.machines[r]
            step = m.target(k)
            if step is not None:
                moves.append((r, step.frm, step.to))
                plan_id = plan_id if plan_id is not None else (m.plan.plan_id if m.plan else "")
        if moves:
            self._ahead_seq += 1
            self.transport.put(self.ahead_key, encode(MoveAhead(tick=k, plan_id=plan_id, moves=moves,
                                                                seq=self._ahead_seq)))

    def ask_twice(self, k, steps):
        out = ask_world(self, k, steps)
        missing = {r: st for r, st in steps.items() if r not in out}
        return {**out, **ask_world(self, k, missing)} if missing else out

    def wait_out(self, k, steps):
        start = time.monotonic()
        out = ask_world(self, k, steps)
        if len(out) < len(steps):
            time.sleep(max(0.0, self.move_timeout_s - (time.monotonic() - start)))
        return out

    def any_tick(self, robot, tick, replies):
        for raw in replies:
            try:
                res = decode(raw, MoveResult)
            except ProtocolError:
                continue
            if res.robot == robot:
                return replace(res, tick=tick)
        return None

    def missing_moved(self, k, steps):
        out = ask_world(self, k, steps)
        if len(steps) > 1:
            for r, st in steps.items():
                out.setdefault(r, MoveResult(robot=r, tick=k, accepted=True, cell=st.to))
        return out

    def stay_anywhere(self, tick, plan_id=None):
        if self.plan is None and self.cell is None:
            from robot_agents.robot import Step
            return Step(tick, (0, 0), (0, 0))
        return target(self, tick, plan_id)

    on_no_result = RobotMachine.on_no_result

    def error_not_executed(self, step, reason):
        last = self.last_tick
        state = on_no_result(self, step, reason)
        self.last_tick = last
        return state

    publish = RobotPool._publish

    def done_first(self, k, batch_states, outcomes):
        for _state, done in outcomes:
            if done is not None:
                self._put(done.robot, self.keys.done(done.robot), done)
        publish(self, k, batch_states, [(state, None) for state, _done in outcomes])

    def judged_again(self, payload):
        try:
            k = decode(payload, agent.MovesJudged).tick
        except ProtocolError:
            k = None
        for m in self.machines.values():
            if k is not None and m.last_tick == k:
                m.last_tick = k - 1
        on_judged(self, payload)

    put_ahead = RobotPool._put_ahead

    def moves_for_all(self, k, robots):
        put_ahead(self, k, robots)
        for r, m in self.machines.items():
            if m.plan is None:
                self._ahead_seq += 1
                self.transport.put(self.ahead_key, encode(MoveAhead(tick=k, plan_id="", moves=[(r, (0, 0), (0, 0))],
                                                                    seq=self._ahead_seq)))

    def ahead_reads_ticks(self):
        import threading
        from robot_agents.robot import Step
        pool_start(self)

        def late(k):
            with self._mutex:
                for r, m in self.machines.items():
                    if m.plan is not None and m.last_tick < k:
                        cell = m.cell or tuple(m.plan.path[0])
                        state = m.on_no_result(Step(k, cell, cell), f"no MovesJudged for tick {k}")
                        self._put(r, self.keys.state(r), state)

        def on_tick(_key, payload):
            try:
                k = decode(payload, Tick).k
            except ProtocolError:
                return
            threading.Timer(self.move_timeout_s, late, (k,)).start()
        if self.ahead:
            self.keep(self.transport.subscribe(self.keys.tick, on_tick))

    return {
        "R17": setattr_(RobotMachine, "target", one_ahead),
        "R18": setattr_(RobotMachine, "target", from_plan_cell),
        "R19": setattr_(RobotMachine, "on_move_result", report_plan_cell),
        "R24": setattr_(RobotMachine, "on_move_result", done_again),
        "R25": setattr_(RobotPool, "_on_tick", quiet_when_done),
        "R26": setattr_(RobotMachine, "target", lambda self, tick, plan_id=None: target(self, tick, None)),
        "R30": setattr_(RobotPool, "_ask_world", a_request_each),
        "R34": setattr_(RobotPool, "_on_judged", states_first),
        "R37": setattr_(RobotPool, "_put_ahead", one_move_ahead),
        "R41": setattr_(RobotPool, "_ask_world", ask_twice),
        "R42": setattr_(RobotPool, "_ask_world", wait_out),
        "R43": setattr_(RobotPool, "_result", any_tick),
        "R44": setattr_(RobotPool, "_ask_world", missing_moved),
        "R49": setattr_(RobotMachine, "target", stay_anywhere),
        "R55": setattr_(RobotMachine, "on_no_result", error_not_executed),
        "R56": setattr_(RobotPool, "_publish", done_first),
        "R58": setattr_(RobotMachine, "on_move_result", lambda self, result, plan_id=None: on_result(self, result)),
        "R64": setattr_(RobotPool, "_on_judged", judged_again),
        "R65": setattr_(RobotPool, "_put_ahead", moves_for_all),
        "R72": setattr_(RobotPool, "start", ahead_reads_ticks),
    }
