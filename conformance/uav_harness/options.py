"""What the UAV suite runs, and the bounds of docs/protocol.md it holds a UAV to."""
from __future__ import annotations

import shlex
import sys
from dataclasses import dataclass

DEFAULT_UAV_CMD = (shlex.quote(sys.executable) + " -m uav_agent --fleet {fleet} --connect {endpoint} "
                   "--mavlink {mavlink} --robots {robots} --tick-timeout {tick_timeout}")
PLACEHOLDERS = "{fleet} {endpoint} {mavlink} {mavlink_port} {robots} {tick_timeout}"
MOVE_TIMEOUT_S = 5.0    # the contract's robot-side move query timeout
SETTLE_S = 2.0          # after the UAV exits: the longest wait for its last messages and token to arrive
ABORT_SLACK_S = 10.0    # beyond the tick timeout, for a failing UAV to say so, end the mission and exit
LATE_JOIN_S = 3.0       # after the UAV's token: when a late robot comes up, unless the UAV dispatches earlier
FIRST_ACK_DELAY_S = 0.5  # the fleet's first ack comes this late, as a real robot's may: a UAV must wait for it
LOST_SETTLE_S = 1.0     # a robot's token is gone this long before the others report the tick it vanished on
FUTURE_DELAY_S = 1.0    # a robot that put a state for a tick not yet put reports that tick this much later
RTL_HOLD_S = 2.0        # after the ground station's RTL is seen in the vehicle: the fleet holds its states so long
RTL_SEEN_S = 5.0        # at most this long for the vehicle to switch to RTL
STARTUP_WAIT_S = 30.0   # docs/protocol.md, Timeouts and waits: the UAV's wait for the world, for every robot, for acks
QUERY_WAIT_S = 10.0     # ... for an answer from world/info and world/record
CALM_TICKS = 3          # a scheduled deviation or stall comes at least this many ticks after the last fault
MUST_DROP = "must be dropped"   # the error text of every message the harness puts that a UAV must drop


@dataclass(frozen=True)
class UavOptions:
    """What the suite runs: the UAV command line and the site it is given (from conftest's --uav-* options)."""
    cmd: str = DEFAULT_UAV_CMD
    map: str = "warehouse-small"
    robots: int = 3
    seed: int = 0
    time_scale: float = 10.0
    tick_timeout_s: float = 3.0
    mission_timeout_s: float = 90.0
    connectivity: int = 4

    @property
    def abort_s(self) -> float:
        """How long after a robot fails the UAV may take to end the mission and exit non-zero."""
        return self.tick_timeout_s + ABORT_SLACK_S
