"""Mutants: our own robot or UAV with exactly one protocol rule broken, to prove the suites catch it.

    python -m conformance.mutants robot --break R9 --id {id} --fleet {fleet} --connect {endpoint}
    python -m conformance.mutants uav --break U8 --fleet {fleet} --connect {endpoint} --mavlink {mavlink} ...

Everything after `--break ID` is the implementation's own command line
(`python -m robot_agents ...` or `python -m uav_agent ...`). Each break is a
small patch of `robot_agents` or `uav_agent` applied before its main runs; the
rule ids and the tests that must fail are in `conformance/rules.py`.
`--break none` runs the implementation unchanged (the control).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import signal
import sys
import time
from typing import Callable

from protocol.bounds import MAX_GRID_SIDE
from protocol.codec import decode, encode
from protocol.errors import ProtocolError
from protocol.messages import (PROTOCOL_VERSION, Done, MoveAhead, MoveResult, Plan, PlanAck, RobotState, Tick,
                               wire_fields)

Patch = Callable[[], None]


def _replace(msg, **changes):
    return dataclasses.replace(msg, **changes)


def setattr_(owner: object, name: str, value: object) -> Patch:
    """The patch that sets `owner.name` to `value`."""
    return lambda: setattr(owner, name, value)


# ---------------------------------------------------------------- robots
def _robot_patches() -> dict[str, Patch]:
    from protocol.transport import Handle
    from robot_agents import agent, robot
    from robot_agents.agent import RobotPool
    from robot_agents.robot import DONE, RobotMachine

    pool_start, pool_put, pool_on_plan = RobotPool.start, RobotPool._put, RobotPool._on_plan
    on_plan, target, on_result, status = (RobotMachine.on_plan, RobotMachine.target, RobotMachine.on_move_result,
                                          RobotMachine.status)
    classify, problem_of = RobotMachine.classify, robot.plan_problem

    def no_token(self):
        real = self.transport.announce
        self.transport.announce = lambda key: Handle(lambda: None)
        try:
            pool_start(self)
        finally:
            self.transport.announce = real

    def token_first(self):
        for r in self.machines:
            self.keep(self.transport.announce(self.keys.alive_robot(r)))
        time.sleep(2.0)
        no_token(self)

    def put_if(keep: Callable[[object], bool]):
        def put(self, rid, key, msg):
            if keep(msg):
                pool_put(self, rid, key, msg)
        return put

    def put_changed(change: Callable[[object], object]):
        def put(self, rid, key, msg):
            pool_put(self, rid, key, change(msg))
        return put

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
            self.plan = _replace(self.plan, plan_id="")
        return on_plan(self, plan)

    def ack_garbage(self, rid, payload):
        try:
            decode(payload, Plan)
        except ProtocolError as exc:
            try:
                pid = str(json.loads(payload).get("plan_id", ""))
            except (ValueError, AttributeError, UnicodeDecodeError):
                pid = ""
            if pid:
                pool_put(self, rid, self.keys.ack(rid), PlanAck(robot=rid, plan_id=pid, ok=False, error=str(exc)))
        pool_on_plan(self, rid, payload)

    def past_ok(self, plan):
        last = self.last_tick
        self.last_tick = 0
        try:
            return on_plan(self, plan)
        finally:
            self.last_tick = last

    def repair_as_plain(self, plan):
        return on_plan(self, _replace(plan, start_tick=0))

    def one_ahead(self, tick, plan_id=None):
        step = target(self, tick + 1, plan_id)
        return None if step is None else _replace(step, tick=tick)

    def from_plan_cell(self, tick, plan_id=None):
        step = target(self, tick, plan_id)
        if step is None or self.plan is None:
            return step
        path = self.plan.path
        return _replace(step, frm=tuple(path[max(0, min(tick - self.base - 1, len(path) - 1))]))

    def report_plan_cell(self, result, plan_id=None):
        state, done = on_result(self, result, plan_id)
        if self.plan is not None:
            path = self.plan.path
            state = _replace(state, cell=tuple(path[max(0, min(result.tick - self.base, len(path) - 1))]))
        return state, done

    def tick0_state(self, rid, payload):
        pool_on_plan(self, rid, payload)
        if self.machines[rid].plan is not None:
            pool_put(self, rid, self.keys.state(rid), self.machines[rid].status(0))

    def never_done(self, tick, note=""):
        state = status(self, tick, note)
        return _replace(state, status="stepping") if state.status == DONE else state

    def done_again(self, result, plan_id=None):
        self.done_sent_for = ""
        return on_result(self, result, plan_id)

    pool_tick = RobotPool._on_tick

    def quiet_when_done(self, payload):
        if all(m.state == DONE for m in self.machines.values()):
            return
        pool_tick(self, payload)

    def execute_all(self, tick):
        if tick.k <= self.last_tick:
            return "run"
        return classify(self, tick)

    def drop_gaps(self, tick):
        kind = classify(self, tick)
        return "old" if kind == "gap" else kind

    def seq_stays(self, rid, key, msg):
        self._seq[rid] = 0
        pool_put(self, rid, key, msg)

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

    def plain_move_key(self):
        self.move_key = self.keys.move
        pool_start(self)

    def batch_key_of_the_first(self):
        self.states_key = self.keys.states_as([min(self.machines)])
        pool_start(self)

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

    def ignore_sigterm(self):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)

    # ---- the rules an independent robot broke unnoticed (R38..)
    def put_raw(change: Callable[[object, str, bytes], None]):
        """A `_put` whose RobotStates go out through `change(self, key, payload)` instead."""
        def put(self, rid, key, msg):
            if not isinstance(msg, RobotState):
                return pool_put(self, rid, key, msg)
            self._seq[rid] += 1
            object.__setattr__(msg, "seq", self._seq[rid])
            change(self, key, encode(msg))
        return put

    def seq_twice(self, key, payload):
        self.transport.put(key, payload.replace(b'"v":1,', b'"v":1,"seq":0,', 1))

    def put_dropping(self, key, payload):
        import zenoh
        self.transport.session.put(key, payload, congestion_control=zenoh.CongestionControl.DROP)

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
                return _replace(res, tick=tick)
        return None

    def missing_moved(self, k, steps):
        out = ask_world(self, k, steps)
        if len(steps) > 1:
            for r, st in steps.items():
                out.setdefault(r, MoveResult(robot=r, tick=k, accepted=True, cell=st.to))
        return out

    real_decode = agent.decode

    def strict_decode(payload, cls, *rest):
        msg = real_decode(payload, cls, *rest)
        known = {"type", "v"} | {f.name for f in wire_fields(cls)}
        unknown = set(json.loads(bytes(payload).partition(b"\0")[0])) - known
        if unknown:
            raise ProtocolError(f"{cls.__name__}: fields it does not know: {sorted(unknown)}")
        return msg

    def rewritten(change: Callable[[object], object]):
        """A decode that first rewrites the JSON it is given (a laxer reader than the document's)."""
        def lax(payload, cls, *rest):
            try:
                body = json.loads(bytes(payload))
            except (ValueError, UnicodeDecodeError):
                return real_decode(payload, cls, *rest)
            return real_decode(json.dumps(change(body)).encode(), cls, *rest)
        return lax

    def ints(x):
        if isinstance(x, float) and x.is_integer():
            return int(x)
        if isinstance(x, list):
            return [ints(v) for v in x]
        if isinstance(x, dict):
            return {k: ints(v) for k, v in x.items()}
        return x

    def clipped(body):
        def clip(c):
            return [min(v, MAX_GRID_SIDE - 1) if type(v) is int else v for v in c] if isinstance(c, list) else c
        if isinstance(body, dict) and body.get("type") == "Plan":
            body = {**body, "goal": clip(body.get("goal")),
                    "path": [clip(c) for c in body.get("path", [])] if isinstance(body.get("path"), list)
                    else body.get("path")}
        return body

    def from_tick_0(self, plan):
        ack = on_plan(self, plan)
        if ack.ok and not plan.start_tick:
            self.base = 0
        return ack

    def stay_anywhere(self, tick, plan_id=None):
        if self.plan is None and self.cell is None:
            from robot_agents.robot import Step
            return Step(tick, (0, 0), (0, 0))
        return target(self, tick, plan_id)

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

    def stepping_on_other_plans(self, tick, plan_id=None):
        if self.plan is not None and plan_id is not None and plan_id != self.plan.plan_id and self.state == "ready":
            self.state = "stepping"
        return target(self, tick, plan_id)

    def refused_is_error(self, result, plan_id=None):
        state, done = on_result(self, result, plan_id)
        return (state if result.accepted else _replace(state, status="error")), done

    on_no_result = RobotMachine.on_no_result

    def sticky_error(self, step, reason):
        self.state = "error"
        return on_no_result(self, step, reason)

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

    def done_off_goal(self, result, plan_id=None):
        before = self.state
        state, done = on_result(self, result, plan_id)
        if before == DONE and self.state != DONE:
            self.state = DONE
            state = _replace(state, status=DONE)
        return state, done

    def loose_plan_keys(self, key, payload):
        text = key.split("/")[-2]
        if text.isdigit() and int(text) in self.machines:
            self._work.put(("plan", (int(text), payload)))

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

    def ignore_sigint(self):
        self.stop_on_signals_real()
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    def exit_without_uav(self):
        import threading
        pool_start(self)
        threading.Timer(0.5, lambda: None if self._uav_seen else self.finish("no UAV")).start()

    open_session = agent.open_session

    def no_wait(*args, **kw):
        return open_session(*args, **{**kw, "wait_s": 0.5})

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

    class Loud:
        """A warning line for every message dropped: no throttle."""
        def __init__(self, prefix, interval_s=1.0):
            self.prefix, self.count = prefix, 0

        def __call__(self, text):
            self.count += 1
            print(f"warning: {self.prefix}: {text}", file=sys.stderr, flush=True)

        def flush(self):
            pass

    def seq_must_grow(self, kind, data):
        payload = data[1] if kind == "plan" else data
        try:
            seq = json.loads(payload).get("seq", 0)
        except (ValueError, AttributeError, UnicodeDecodeError):
            seq = 0
        last = self.__dict__.setdefault("_mutant_seq", {})
        if isinstance(seq, int) and seq <= last.get(kind, 0):
            return
        last[kind] = seq
        handle(self, kind, data)

    handle = RobotPool._handle

    return {
        "R1": setattr_(RobotPool, "start", no_token),
        "R2": setattr_(RobotPool, "start", token_first),
        "R3": setattr_(RobotPool, "_put", put_changed(
            lambda m: _replace(m, robot=m.robot + 1) if isinstance(m, RobotState) else m)),
        "R4": setattr_(RobotPool, "_put", put_if(lambda m: not (isinstance(m, PlanAck) and m.ok))),
        "R5": setattr_(robot, "plan_problem", lambda plan, rid, c: problem_of(plan, plan.robot, c)),
        "R6": setattr_(RobotMachine, "on_plan", accept_empty),
        "R7": setattr_(robot, "plan_problem", problem_without("connected move")),
        "R8": setattr_(robot, "plan_problem", problem_without("not at the goal")),
        "R9": setattr_(RobotMachine, "on_plan", no_start_check),
        "R10": setattr_(robot, "plan_problem", lambda plan, rid, c: problem_of(_replace(plan, connectivity=0), rid, c)),
        "R11": setattr_(RobotPool, "_on_plan", once_per_id),
        "R12": setattr_(RobotMachine, "on_plan", take_same_id),
        "R13": setattr_(RobotMachine, "_ack", lambda self, pid, ok, error: PlanAck(
            robot=self.robot_id, plan_id=pid, ok=ok, error="" if not ok else error, protocol=PROTOCOL_VERSION)),
        "R14": setattr_(RobotPool, "_on_plan", ack_garbage),
        "R15": setattr_(RobotMachine, "on_plan", past_ok),
        "R16": setattr_(RobotMachine, "on_plan", repair_as_plain),
        "R17": setattr_(RobotMachine, "target", one_ahead),
        "R18": setattr_(RobotMachine, "target", from_plan_cell),
        "R19": setattr_(RobotMachine, "on_move_result", report_plan_cell),
        "R20": setattr_(RobotPool, "_on_plan", tick0_state),
        "R21": setattr_(RobotPool, "_put", put_changed(
            lambda m: _replace(m, plan_id="") if isinstance(m, RobotState) else m)),
        "R22": setattr_(RobotMachine, "status", never_done),
        "R23": setattr_(RobotPool, "_put", put_if(lambda m: not (isinstance(m, RobotState) and m.status == "error"))),
        "R24": setattr_(RobotMachine, "on_move_result", done_again),
        "R25": setattr_(RobotPool, "_on_tick", quiet_when_done),
        "R26": setattr_(RobotMachine, "target", lambda self, tick, plan_id=None: target(self, tick, None)),
        "R27": setattr_(RobotMachine, "classify", execute_all),
        "R28": setattr_(RobotMachine, "classify", drop_gaps),
        "R29": setattr_(RobotPool, "_put", seq_stays),
        "R30": setattr_(RobotPool, "_ask_world", a_request_each),
        "R31": setattr_(RobotPool, "_on_end", lambda self, key, payload: None),
        "R32": setattr_(agent.Lifecycle, "stop_on_signals", ignore_sigterm),
        "R33": setattr_(RobotPool, "_on_uav", lambda self, key, alive: None),
        "R34": setattr_(RobotPool, "_on_judged", states_first),
        "R35": setattr_(RobotPool, "start", plain_move_key),
        "R36": setattr_(RobotPool, "start", batch_key_of_the_first),
        "R37": setattr_(RobotPool, "_put_ahead", one_move_ahead),
        "R38": setattr_(RobotPool, "_put", put_raw(seq_twice)),
        "R39": setattr_(RobotPool, "_put", put_raw(put_dropping)),
        "R40": setattr_(agent, "MOVE_TIMEOUT_S", 1.0),
        "R41": setattr_(RobotPool, "_ask_world", ask_twice),
        "R42": setattr_(RobotPool, "_ask_world", wait_out),
        "R43": setattr_(RobotPool, "_result", any_tick),
        "R44": setattr_(RobotPool, "_ask_world", missing_moved),
        "R45": setattr_(agent, "decode", strict_decode),
        "R46": setattr_(agent, "decode", rewritten(ints)),
        "R47": setattr_(agent, "decode", rewritten(clipped)),
        "R48": setattr_(RobotMachine, "on_plan", from_tick_0),
        "R49": setattr_(RobotMachine, "target", stay_anywhere),
        "R50": setattr_(RobotMachine, "on_plan", first_start_known),
        "R51": setattr_(RobotMachine, "on_plan", remember_ids),
        "R52": setattr_(RobotMachine, "target", stepping_on_other_plans),
        "R53": setattr_(RobotMachine, "on_move_result", refused_is_error),
        "R54": setattr_(RobotMachine, "on_no_result", sticky_error),
        "R55": setattr_(RobotMachine, "on_no_result", error_not_executed),
        "R56": setattr_(RobotPool, "_publish", done_first),
        "R57": setattr_(RobotPool, "_on_plan", done_at_ack),
        "R58": setattr_(RobotMachine, "on_move_result", lambda self, result, plan_id=None: on_result(self, result)),
        "R59": setattr_(RobotMachine, "on_plan", done_again_when_resent),
        "R60": setattr_(RobotMachine, "on_move_result", done_off_goal),
        "R61": setattr_(RobotPool, "_on_any_plan", loose_plan_keys),
        "R62": setattr_(RobotPool, "_publish", lambda self, k, batch_states, outcomes: publish(self, k, True, outcomes)),
        "R63": setattr_(RobotPool, "_on_plan", no_move_when_resent),
        "R64": setattr_(RobotPool, "_on_judged", judged_again),
        "R65": setattr_(RobotPool, "_put_ahead", moves_for_all),
        "R66": lambda: (setattr(agent.Lifecycle, "stop_on_signals_real", agent.Lifecycle.stop_on_signals),
                        setattr(agent.Lifecycle, "stop_on_signals", ignore_sigint)) and None,
        "R67": setattr_(RobotPool, "start", exit_without_uav),
        # Waits out its pending move query at the end. Joining longer alone ends with the 5 s query, as long
        # as the rule's window: on a loaded machine that mutant exited inside it (CI, 2026-11-28).
        "R68": lambda: [setattr(agent, "JOIN_TIMEOUT_S", 30.0), setattr(agent, "MOVE_TIMEOUT_S", 30.0)] and None,
        "R69": setattr_(RobotPool, "_on_end", lambda self, key, payload: self.finish("anything on mission/end")),
        "R70": setattr_(agent, "open_session", no_wait),
        "R71": setattr_(RobotMachine, "_ack", lambda self, pid, ok, error: PlanAck(
            robot=self.robot_id, plan_id=pid, ok=ok, error=error)),
        "R72": setattr_(RobotPool, "start", ahead_reads_ticks),
        "R73": setattr_(agent, "Throttled", Loud),
        "R74": setattr_(RobotPool, "_handle", seq_must_grow),
    }


def _robot_main(argv: list[str]) -> int:
    from protocol.process import command_main, one_command
    from robot_agents.agent import add_robot_arguments, robot_command

    return command_main(one_command("python -m conformance.mutants robot", "A robot with one rule broken.",
                                    add_robot_arguments, robot_command), argv)


# ---------------------------------------------------------------- UAVs
def _uav_patches() -> dict[str, Patch]:
    from protocol.errors import MissionError
    from protocol.messages import MissionEnd, MissionStatus, StateBatch
    from protocol.transport import Handle
    from uav_agent import preview, recovery, watch
    from uav_agent.fleet import FleetLink
    from uav_agent.flight import Flight
    from uav_agent.mission import context, dispatch, execute, finish, repair, verify
    from uav_agent.mission import plan as planning
    from uav_agent.mission.context import MissionContext
    from uav_agent.planning import pipeline, validator
    from uav_agent.planning.build import interpreted
    from uav_agent.pose_feed import PoseFeed

    transport_of, send, end, decode_of, wait_until = (context.open_transport, dispatch.send, finish.end,
                                                      FleetLink._decode, FleetLink.wait_until)
    take_state, on_robot_alive, wait_tick, recover = (FleetLink._take_state, FleetLink._on_robot_alive,
                                                      FleetLink.wait_tick, repair.recover)
    verified, query, replan, pose_feed_init = verify.run, context.query, recovery.replan, PoseFeed.__init__
    flown: dict[str, MissionContext] = {}   # the mission being flown, for patches of the fleet's link that need its plan

    def no_uav_token(cfg):
        t = transport_of(cfg)
        real = t.announce
        t.announce = lambda key: Handle(lambda: None) if key.endswith("/alive/uav") else real(key)
        return t

    def plan_to_a_stranger(ctx, plan, first=False):
        if first:
            rid = max(plan.ids) + 1000
            ctx.transport.put(ctx.keys.plan(rid), encode(Plan(
                robot=rid, plan_id=plan.plan_id, path=[(0, 0)], goal=(0, 0), seq=ctx.next_seq())))
        return send(ctx, plan, first)

    def made_with(cls, **change: Callable[[dict], object]):
        """A stand-in for message class `cls` in a mission module that changes the fields it is built with."""
        def make(**kw):
            return cls(**{**kw, **{k: f(kw) for k, f in change.items()}})
        return make

    def through_a_goal(plan_plain):
        def plan(free, starts, goals, **kw):
            # Robot 0 waits until robot 1 has arrived, then drives across robot 1's goal to its own.
            from uav_agent.planning.paper.astar import astar

            result = plan_plain(free, starts, goals, **kw)
            paths = list(result.paths)
            if len(paths) >= 2:
                c = kw.get("connectivity", 4)
                a, goal_a, goal_b = result.starts[0], result.goals[0], result.goals[1]
                paths[0] = ([tuple(a)] * len(paths[1]) + astar(free, a, goal_b, c)[1:]
                            + astar(free, goal_b, goal_a, c)[1:])
            return dataclasses.replace(result, paths=paths)
        return plan

    def conflicting():
        # Both ways the UAV plans: compiled, and interpreted while a fresh clone's kernels compile (in a
        # child process, which this patch does not reach: on a fresh clone the mutant waits for the compile).
        pipeline.plan_mission = through_a_goal(pipeline.plan_mission)
        interpreted.plan_interpreted = through_a_goal(interpreted.plan_interpreted)
        planning.plan_while_compiling = lambda ctx, *args: None
        validator.check = lambda *a, **k: None

    def skip_ack_wait(self, ready, timeout, failure, abort=None):
        if "acknowledge" in failure():
            return
        wait_until(self, ready, timeout, failure, abort)

    def end_twice(ctx, completed, reason):
        end(ctx, completed, reason)
        ctx.ended = False
        end(ctx, completed, reason)

    def refusal_is_ack(self, key, payload, cls):
        msg = decode_of(self, key, payload, cls)
        return _replace(msg, ok=True, error="") if isinstance(msg, PlanAck) and not msg.ok else msg

    def any_robot(self, key, payload, cls):
        try:
            return decode(payload, cls)
        except ProtocolError as exc:
            self._reject(key, str(exc))
            return None

    def believe(ctx):
        # A believer waits for the claims: a robot's Done follows its last state, and may still be on
        # its way when the last tick is over (the mutant then failed the liar for want of its Done).
        ids = ctx.plans.ids
        with ctx.fleet.cv:
            ctx.fleet.cv.wait_for(lambda: all(r in ctx.fleet.done for r in ids), timeout=3.0)
        ctx.arrivals.verified = {r: r in ctx.fleet.done for r in ids}

    def both(*patches: Patch) -> Patch:
        return lambda: [p() for p in patches] and None

    def one_left_out(free, goals, working, blocked, **options):
        # Every repair leaves out its highest working robot (as if it were stopped): it gets no plan.
        if len(working) > 1:
            out = max(working)
            blocked = {**blocked, out: working[out]}
            working = {r: c for r, c in working.items() if r != out}
        return replan(free, goals, working, blocked, **options)

    def keeps_the_lost(self, key, alive):
        if alive:
            on_robot_alive(self, key, alive)

    def errors_ignored(self, robot, tick, cell, status, error):
        take_state(self, robot, tick, cell, "stepping" if status == "error" else status, error)

    def remembered(ctx, plan, first=False):
        flown["mission"] = ctx
        return send(ctx, plan, first)

    def plan_cells_believed(self, robot, tick, cell, status, error):
        m = flown.get("mission")
        if m is not None and m.plans.now is not None and robot in m.plans.now.paths:
            cell = m.plans.now.cell(robot, tick)
        take_state(self, robot, tick, cell, status, error)

    def gives_up_at_the_third_repair(ctx, k, faults):
        n = ctx.__dict__["_mutant_repairs"] = ctx.__dict__.get("_mutant_repairs", 0) + 1
        if n >= 3:
            raise MissionError(f"gave up after {n - 1} repairs")
        return recover(ctx, k, faults)

    def every_entry(self, key, payload):
        try:
            msg = decode(payload, StateBatch)
        except ProtocolError as exc:
            self._reject(key, str(exc))
            return
        if not self._from_the_future(key, msg.tick):
            with self.cv:
                for robot, cell, status, _plan, error in msg.states:
                    take_state(self, robot, msg.tick, cell, status, error)

    def flicker(ctx, plan, first=False):
        if first:
            ctx.token.close()
            time.sleep(0.2)
            ctx.token = ctx.transport.announce(ctx.keys.alive_uav)
        return send(ctx, plan, first)

    def needs_done(ctx):
        verified(ctx)
        v = ctx.arrivals.verified
        for r in v:
            v[r] = v[r] and r in ctx.fleet.done

    def forever_if(words: str):
        def wait(self, ready, timeout, failure, *args, **kw):
            return wait_until(self, ready, 1e6 if words in failure() else timeout, failure, *args, **kw)
        return wait

    def until_it_answers(transport, key, request, reply_type, what, *args, **kw):
        while True:
            try:
                return query(transport, key, request, reply_type, what, *args, **kw)
            except MissionError:
                if what != "info":
                    raise
                time.sleep(1.0)

    def unacked_repair_is_fatal(ctx, plan, first=False):
        failed = send(ctx, plan, first)
        if failed and not first:
            raise MissionError(f"robots {failed} did not take repair {plan.plan_id}")
        return failed

    def no_executing_status(**kw):
        return MissionStatus(**({**kw, "tick": 0} if kw.get("phase") == "executing" else kw))

    def no_event(**kw):
        raise RuntimeError("the mutant publishes no event")

    def slow_poses(self, flight, publish, t0=None, period_s=0.2):
        pose_feed_init(self, flight, publish, t0, 2.0)

    def hurried(ctx, k, faults):
        ctx.fleet.__dict__["_mutant_hurry"] = True
        try:
            return recover(ctx, k, faults)
        finally:
            ctx.fleet.__dict__["_mutant_hurry"] = False

    def unsettled(self, robots, k, timeout, interrupt):
        return {} if self.__dict__.get("_mutant_hurry") else wait_tick(self, robots, k, timeout, interrupt)

    def plan_after_end(ctx, completed, reason):
        end(ctx, completed, reason)
        plan = ctx.plans.now
        if plan is not None:
            r = plan.ids[0]
            ctx.transport.put(ctx.keys.plan(r), encode(Plan(
                robot=r, plan_id=plan.plan_id, path=plan.paths[r], goal=plan.goals[r], start_tick=plan.start_tick,
                seq=ctx.next_seq())))

    return {
        "U1": setattr_(context, "open_transport", no_uav_token),
        "U2": setattr_(dispatch, "send", plan_to_a_stranger),
        "U3": setattr_(dispatch, "Plan", made_with(Plan, goal=lambda kw: tuple(kw["path"][0]))),
        "U4": conflicting,
        "U5": setattr_(FleetLink, "wait_until", skip_ack_wait),
        "U6": setattr_(execute, "Tick", made_with(Tick, k=lambda kw: kw["k"] + 1)),
        "U7": setattr_(execute, "Tick", made_with(Tick, ticks=lambda kw: kw["ticks"] + 1)),
        "U8": both(setattr_(FleetLink, "wait_tick", lambda self, robots, k, timeout, interrupt: {}),
                   setattr_(execute, "repaired", lambda ctx, k, faults: None)),
        "U9": setattr_(MissionContext, "next_seq", lambda self: 1),
        "U10": setattr_(finish, "end", end_twice),
        "U11": setattr_(Flight, "land", lambda self, timeout_s=120.0: None),
        "U12": setattr_(FleetLink, "_decode", refusal_is_ack),
        "U13": setattr_(dispatch, "Plan", made_with(Plan, start_tick=lambda kw: 0)),
        "U14": both(setattr_(verify, "run", believe), setattr_(repair, "off_goal", lambda ctx: [])),
        "U15": setattr_(FleetLink, "_decode", any_robot),
        "U16": setattr_(dispatch, "PLAN_RESEND_S", 6.0),
        "U17": setattr_(recovery, "replan", one_left_out),
        "U18": setattr_(FleetLink, "_on_robot_alive", keeps_the_lost),
        "U19": setattr_(FleetLink, "_take_state", errors_ignored),
        "U20": both(setattr_(dispatch, "send", remembered), setattr_(FleetLink, "_take_state", plan_cells_believed)),
        "U21": setattr_(repair, "rejoining", lambda ctx: []),
        "U22": setattr_(repair, "recover", gives_up_at_the_third_repair),
        "U23": setattr_(FleetLink, "_from_the_future", lambda self, key, tick: False),
        "U24": setattr_(FleetLink, "_on_state_batch", every_entry),
        "U25": setattr_(dispatch, "send", flicker),
        "U26": setattr_(verify, "run", needs_done),
        "U27": setattr_(watch, "FOREIGN_MODES", set()),
        "U28": setattr_(FleetLink, "wait_until", forever_if("no world")),
        "U29": setattr_(context, "query", until_it_answers),
        "U30": setattr_(FleetLink, "wait_until", forever_if("came alive")),
        "U31": setattr_(dispatch, "send", unacked_repair_is_fatal),
        "U32": setattr_(context, "MissionStatus", no_executing_status),
        "U33": setattr_(context, "MissionEvent", no_event),
        "U34": setattr_(PoseFeed, "__init__", slow_poses),
        "U35": setattr_(preview, "preview_frame", lambda frame, side=preview.PREVIEW_SIDE: frame),
        "U36": both(setattr_(repair, "recover", hurried), setattr_(FleetLink, "wait_tick", unsettled)),
        "U37": setattr_(finish, "end", plan_after_end),
        "U38": setattr_(finish, "MissionEnd", made_with(MissionEnd, reason=lambda kw: "")),
    }


def _uav_main(argv: list[str]) -> int:
    from protocol.process import command_main
    from uav_agent.cli import build_parser

    return command_main(build_parser, argv)


SIDES = {"robot": (_robot_patches, _robot_main), "uav": (_uav_patches, _uav_main)}


def breaks(side: str) -> list[str]:
    """The rule ids that `side` has a mutant for."""
    return list(SIDES[side][0]())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m conformance.mutants", description=__doc__.splitlines()[0],
                                epilog="Anything after --break ID is the implementation's own command line.")
    p.add_argument("side", choices=list(SIDES))
    p.add_argument("--break", dest="rule", required=True, metavar="ID", help="the rule to break (R1.., U1..), or none")
    args, rest = p.parse_known_args(sys.argv[1:] if argv is None else argv)
    patches, run = SIDES[args.side]
    table = patches()
    if args.rule != "none":
        if args.rule not in table:
            p.error(f"no {args.side} mutant {args.rule!r}: choose one of {', '.join(table)} or none")
        table[args.rule]()
    return run(rest)


if __name__ == "__main__":
    sys.exit(main())
