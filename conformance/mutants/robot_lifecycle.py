"""Robot mutants of starting and ending: tokens, signals, leaving (docs/protocol.md, Startup order, End of mission)."""
from __future__ import annotations

import signal
import time

from .patching import Patch, setattr_


def patches() -> dict[str, Patch]:
    """The mutants by rule id. The real methods are taken now, before any patch: each mutant builds on them."""
    from protocol.transport import Handle
    from robot_agents import agent
    from robot_agents.agent import RobotPool

    pool_start = RobotPool.start

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

    def ignore_sigterm(self):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)

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

    return {
        "R1": setattr_(RobotPool, "start", no_token),
        "R2": setattr_(RobotPool, "start", token_first),
        "R31": setattr_(RobotPool, "_on_end", lambda self, key, payload: None),
        "R32": setattr_(agent.Lifecycle, "stop_on_signals", ignore_sigterm),
        "R33": setattr_(RobotPool, "_on_uav", lambda self, key, alive: None),
        "R66": lambda: (setattr(agent.Lifecycle, "stop_on_signals_real", agent.Lifecycle.stop_on_signals),
                        setattr(agent.Lifecycle, "stop_on_signals", ignore_sigint)) and None,
        "R67": setattr_(RobotPool, "start", exit_without_uav),
        # Waits out its pending move query at the end. Joining longer alone ends with the 5 s query, as long
        # as the rule's window: on a loaded machine that mutant exited inside it (CI, 2026-11-28).
        "R68": lambda: [setattr(agent, "JOIN_TIMEOUT_S", 30.0), setattr(agent, "MOVE_TIMEOUT_S", 30.0)] and None,
        "R69": setattr_(RobotPool, "_on_end", lambda self, key, payload: self.finish("anything on mission/end")),
        "R70": setattr_(agent, "open_session", no_wait),
    }
