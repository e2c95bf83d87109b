"""UAV mutants: our UAV (uav_agent) with one rule of docs/protocol.md broken each."""
from __future__ import annotations

import dataclasses
import time
from typing import Callable

from protocol.errors import ProtocolError
from protocol.codec import decode, encode
from protocol.messages import Plan, PlanAck, Tick

from .patching import Patch, replace, setattr_


def patches() -> dict[str, Patch]:
    """The mutants by rule id. The real methods are taken now, before any patch: each mutant builds on them."""
    from protocol.errors import MissionError
    from protocol.messages import MissionEnd, MissionStatus, StateBatch
    from protocol.transport import Handle
    from uav_agent import preview, recovery, watch, world_query
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
    verified, query, replan, pose_feed_init = verify.run, world_query.query, recovery.replan, PoseFeed.__init__
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
        return replace(msg, ok=True, error="") if isinstance(msg, PlanAck) and not msg.ok else msg

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
        "U29": setattr_(world_query, "query", until_it_answers),
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
