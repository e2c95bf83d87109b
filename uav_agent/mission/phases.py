"""The mission's phases in order, over one context: start -> survey -> perceive -> plan -> dispatch
-> execute -> verify (-> repair -> execute ...) -> land -> report. A failure lands the vehicle and
still writes the report; so does a stop from outside."""
from __future__ import annotations

import secrets
from typing import Any

from ..progress import Progress
from . import context, dispatch, execute, finish, movers, plan, repair, score, start, survey, verify
from .config import MissionConfig
from .context import MissionContext
from .state import PlanState


def run_mission(cfg: MissionConfig, progress: Progress | None = None) -> dict[str, Any]:
    """Fly the mission `cfg` describes; its report (also written to cfg.out, if given)."""
    transport = context.open_transport(cfg)
    try:
        ctx = MissionContext(cfg, transport, progress)
    except BaseException:
        transport.close()
        raise
    try:
        start.connect(ctx)
        survey.fly(ctx)
        model = survey.perceive(ctx)
        result = plan.plan(ctx, model)
        ids = ctx.plans.ids
        first = PlanState(secrets.token_hex(4), 0, dict(zip(ids, map(list, result.paths))), dict(zip(ids, result.goals)))
        dispatch.send(ctx, movers.start(ctx, model, first), first=True)
        while True:
            execute.run(ctx)
            verify.run(ctx)
            repair.drop_the_gone(ctx)
            back, off = repair.rejoining(ctx), repair.off_goal(ctx)
            if not back and not off:
                break
            execute.repaired(ctx, ctx.tick, {"rejoin": back, "deviation": off})
        ctx.check_vehicle()
        ctx.watch.expect_airborne(False)
        finish.end(ctx, verify.outcome(ctx) != "failed", verify.reason(ctx))
        finish.land(ctx)
        score.finish_report(ctx)
        return ctx.report
    except Exception as exc:
        finish.aborted(ctx, exc)
        raise
    except BaseException as exc:   # SIGTERM (protocol.process unwinds it as SystemExit) or SIGINT
        finish.stopped(ctx, exc)
        raise
    finally:
        finish.close(ctx)
