"""Robot mutants of what a robot puts and reads: keys, fields, statuses, seq, QoS (docs/protocol.md, Keys, Messages)."""
from __future__ import annotations

import json
import sys
from typing import Callable

from protocol.errors import ProtocolError
from protocol.bounds import MAX_GRID_SIDE
from protocol.codec import decode, encode
from protocol.messages import Plan, PlanAck, RobotState, wire_fields

from .patching import Patch, put_changed, put_if, replace, setattr_


def patches() -> dict[str, Patch]:
    """The mutants by rule id. The real methods are taken now, before any patch: each mutant builds on them."""
    from robot_agents import agent
    from robot_agents.agent import RobotPool
    from robot_agents.robot import DONE, RobotMachine

    pool_start, pool_put, pool_on_plan = RobotPool.start, RobotPool._put, RobotPool._on_plan
    on_result, status, classify, target = (RobotMachine.on_move_result, RobotMachine.status, RobotMachine.classify,
                                           RobotMachine.target)

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

    def tick0_state(self, rid, payload):
        pool_on_plan(self, rid, payload)
        if self.machines[rid].plan is not None:
            pool_put(self, rid, self.keys.state(rid), self.machines[rid].status(0))

    def never_done(self, tick, note=""):
        state = status(self, tick, note)
        return replace(state, status="stepping") if state.status == DONE else state

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

    def plain_move_key(self):
        self.move_key = self.keys.move
        pool_start(self)

    def batch_key_of_the_first(self):
        self.states_key = self.keys.states_as([min(self.machines)])
        pool_start(self)

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

    def stepping_on_other_plans(self, tick, plan_id=None):
        if self.plan is not None and plan_id is not None and plan_id != self.plan.plan_id and self.state == "ready":
            self.state = "stepping"
        return target(self, tick, plan_id)

    def refused_is_error(self, result, plan_id=None):
        state, done = on_result(self, result, plan_id)
        return (state if result.accepted else replace(state, status="error")), done

    on_no_result = RobotMachine.on_no_result

    def sticky_error(self, step, reason):
        self.state = "error"
        return on_no_result(self, step, reason)

    publish = RobotPool._publish

    def done_off_goal(self, result, plan_id=None):
        before = self.state
        state, done = on_result(self, result, plan_id)
        if before == DONE and self.state != DONE:
            self.state = DONE
            state = replace(state, status=DONE)
        return state, done

    def loose_plan_keys(self, key, payload):
        text = key.split("/")[-2]
        if text.isdigit() and int(text) in self.machines:
            self._work.put(("plan", (int(text), payload)))

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
        "R3": setattr_(RobotPool, "_put", put_changed(pool_put,
            lambda m: replace(m, robot=m.robot + 1) if isinstance(m, RobotState) else m)),
        "R14": setattr_(RobotPool, "_on_plan", ack_garbage),
        "R20": setattr_(RobotPool, "_on_plan", tick0_state),
        "R21": setattr_(RobotPool, "_put", put_changed(pool_put,
            lambda m: replace(m, plan_id="") if isinstance(m, RobotState) else m)),
        "R22": setattr_(RobotMachine, "status", never_done),
        "R23": setattr_(RobotPool, "_put", put_if(
            pool_put, lambda m: not (isinstance(m, RobotState) and m.status == "error"))),
        "R27": setattr_(RobotMachine, "classify", execute_all),
        "R28": setattr_(RobotMachine, "classify", drop_gaps),
        "R29": setattr_(RobotPool, "_put", seq_stays),
        "R35": setattr_(RobotPool, "start", plain_move_key),
        "R36": setattr_(RobotPool, "start", batch_key_of_the_first),
        "R38": setattr_(RobotPool, "_put", put_raw(seq_twice)),
        "R39": setattr_(RobotPool, "_put", put_raw(put_dropping)),
        "R40": setattr_(agent, "MOVE_TIMEOUT_S", 1.0),
        "R45": setattr_(agent, "decode", strict_decode),
        "R46": setattr_(agent, "decode", rewritten(ints)),
        "R47": setattr_(agent, "decode", rewritten(clipped)),
        "R52": setattr_(RobotMachine, "target", stepping_on_other_plans),
        "R53": setattr_(RobotMachine, "on_move_result", refused_is_error),
        "R54": setattr_(RobotMachine, "on_no_result", sticky_error),
        "R60": setattr_(RobotMachine, "on_move_result", done_off_goal),
        "R61": setattr_(RobotPool, "_on_any_plan", loose_plan_keys),
        "R62": setattr_(RobotPool, "_publish", lambda self, k, batch_states, outcomes: publish(self, k, True, outcomes)),
        "R71": setattr_(RobotMachine, "_ack", lambda self, pid, ok, error: PlanAck(
            robot=self.robot_id, plan_id=pid, ok=ok, error=error)),
        "R73": setattr_(agent, "Throttled", Loud),
        "R74": setattr_(RobotPool, "_handle", seq_must_grow),
    }
