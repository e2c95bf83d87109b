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

from protocol.errors import ProtocolError
from protocol.messages import MoveAhead, Plan, PlanAck, RobotState, Tick, decode, encode

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

    def first_robot_only(self, k, steps):
        first = min(steps)
        return ask_world(self, k, {first: steps[first]})

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
            robot=self.robot_id, plan_id=pid, ok=ok, error="" if not ok else error)),
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
        "R30": setattr_(RobotPool, "_ask_world", first_robot_only),
        "R31": setattr_(RobotPool, "_on_end", lambda self, key, payload: None),
        "R32": setattr_(agent.Lifecycle, "stop_on_signals", ignore_sigterm),
        "R33": setattr_(RobotPool, "_on_uav", lambda self, key, alive: None),
        "R34": setattr_(RobotPool, "_on_judged", states_first),
        "R35": setattr_(RobotPool, "start", plain_move_key),
        "R36": setattr_(RobotPool, "start", batch_key_of_the_first),
        "R37": setattr_(RobotPool, "_put_ahead", one_move_ahead),
    }


def _robot_main(argv: list[str]) -> int:
    from protocol.process import command_main, one_command
    from robot_agents.agent import add_robot_arguments, robot_command

    return command_main(one_command("python -m conformance.mutants robot", "A robot with one rule broken.",
                                    add_robot_arguments, robot_command), argv)


# ---------------------------------------------------------------- UAVs
def _uav_patches() -> dict[str, Patch]:
    from protocol.transport import Handle
    from uav_agent import mission
    from uav_agent.fleet import FleetLink
    from uav_agent.flight import Flight
    from uav_agent.mission import Mission
    from uav_agent.planning import interpreted, pipeline, validator

    transport_of, dispatch, end, decode_of, wait_until = (mission._transport, Mission._dispatch, Mission._end,
                                                          FleetLink._decode, FleetLink.wait_until)

    def no_uav_token(cfg):
        t = transport_of(cfg)
        real = t.announce
        t.announce = lambda key: Handle(lambda: None) if key.endswith("/alive/uav") else real(key)
        return t

    def plan_to_a_stranger(self, plan, first=False):
        if first:
            rid = max(plan.ids) + 1000
            self.transport.put(self.keys.plan(rid), mission.encode(Plan(
                robot=rid, plan_id=plan.plan_id, path=[(0, 0)], goal=(0, 0), seq=self._next())))
        return dispatch(self, plan, first)

    def made_with(cls, **change: Callable[[dict], object]):
        """A stand-in for message class `cls` in the mission module that changes the fields it is built with."""
        def make(**kw):
            return cls(**{**kw, **{k: f(kw) for k, f in change.items()}})
        return make

    def through_a_goal(plan_plain):
        def plan(free, starts, goals, **kw):
            # Robot 0 waits until robot 1 has arrived, then drives across robot 1's goal to its own.
            from uav_agent.planning.astar import astar

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
        # Both ways the UAV plans: compiled, and interpreted while a fresh clone's kernels compile.
        pipeline.plan_mission = through_a_goal(pipeline.plan_mission)
        interpreted.plan_interpreted = through_a_goal(interpreted.plan_interpreted)
        validator.check = lambda *a, **k: None

    def skip_ack_wait(self, ready, timeout, failure, abort=None):
        if "acknowledge" in failure():
            return
        wait_until(self, ready, timeout, failure, abort)

    def end_twice(self, completed, reason):
        end(self, completed, reason)
        self._ended = False
        end(self, completed, reason)

    def refusal_is_ack(self, key, payload, cls):
        msg = decode_of(self, key, payload, cls)
        return _replace(msg, ok=True, error="") if isinstance(msg, PlanAck) and not msg.ok else msg

    def any_robot(self, key, payload, cls):
        try:
            return decode(payload, cls)
        except ProtocolError as exc:
            self._reject(key, str(exc))
            return None

    def believe(self):
        # A believer waits for the claims: a robot's Done follows its last state, and may still be on
        # its way when the last tick is over (the mutant then failed the liar for want of its Done).
        with self.fleet.cv:
            self.fleet.cv.wait_for(lambda: all(r in self.fleet.done for r in self.ids), timeout=3.0)
        self.verified = {r: r in self.fleet.done for r in self.ids}

    def both(*patches: Patch) -> Patch:
        return lambda: [p() for p in patches] and None

    return {
        "U1": setattr_(mission, "_transport", no_uav_token),
        "U2": setattr_(Mission, "_dispatch", plan_to_a_stranger),
        "U3": setattr_(mission, "Plan", made_with(Plan, goal=lambda kw: tuple(kw["path"][0]))),
        "U4": conflicting,
        "U5": setattr_(FleetLink, "wait_until", skip_ack_wait),
        "U6": setattr_(mission, "Tick", made_with(Tick, k=lambda kw: kw["k"] + 1)),
        "U7": setattr_(mission, "Tick", made_with(Tick, ticks=lambda kw: kw["ticks"] + 1)),
        "U8": both(setattr_(FleetLink, "wait_tick", lambda self, robots, k, timeout, interrupt: {}),
                   setattr_(Mission, "_recover", lambda self, k, faults: None)),
        "U9": setattr_(Mission, "_next", lambda self: 1),
        "U10": setattr_(Mission, "_end", end_twice),
        "U11": setattr_(Flight, "land", lambda self, timeout_s=120.0: None),
        "U12": setattr_(FleetLink, "_decode", refusal_is_ack),
        "U13": setattr_(mission, "Plan", made_with(Plan, start_tick=lambda kw: 0)),
        "U14": both(setattr_(Mission, "_verify", believe), setattr_(Mission, "_off_goal", lambda self: [])),
        "U15": setattr_(FleetLink, "_decode", any_robot),
        "U16": setattr_(mission, "PLAN_RESEND_S", 6.0),
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
