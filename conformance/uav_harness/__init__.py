"""A harness that plays router, world and robots around a UAV implementation under test.

The UAV conformance suite (the `test_uav_*.py` files of `conformance`) starts
the UAV from a command line and surrounds it with: a Zenoh router on a free
loopback port, our real world in this process (ground truth, move service,
camera, and the simulated MAVLink vehicle on a free UDP port), and a fleet of
fake robots that the suite controls. The robots keep the contract of
docs/protocol.md (or break it on purpose: they stall, err, deviate, vanish, go
deaf or mute), and record everything the UAV sends them, with the checks that
can only be made at the moment a message arrives (was this robot's token up?
had every robot reported the previous tick?). The site records what the world
saw: when each image's shutter opened, and the images it sent.

One job a module: `options` (what is run, and the bounds), `processes` (the
UAV's command line), `site` (the world), `fleet` with `arrivals` and
`misbehaviour` (the robots), `plans` (what a robot must refuse), `mission` and
`stranded` (one run each).
"""
from __future__ import annotations

from .fleet import FakeFleet
from .fleet_state import FakeRobot, Observed
from .misbehaviour import Misbehaviour, junk
from .mission import MissionRun, error_lines, run_mission
from .options import (ABORT_SLACK_S, CALM_TICKS, DEFAULT_UAV_CMD, FIRST_ACK_DELAY_S, FUTURE_DELAY_S, LATE_JOIN_S,
                      LOST_SETTLE_S, MOVE_TIMEOUT_S, MUST_DROP, PLACEHOLDERS, QUERY_WAIT_S, RTL_HOLD_S, RTL_SEEN_S,
                      SETTLE_S, STARTUP_WAIT_S, UavOptions)
from .plans import plan_problem, step_ok
from .processes import free_udp_port, start_process, uav_command
from .site import Shutter, Site
from .stranded import WORLDS, run_stranded

__all__ = ["ABORT_SLACK_S", "CALM_TICKS", "DEFAULT_UAV_CMD", "FIRST_ACK_DELAY_S", "FUTURE_DELAY_S", "LATE_JOIN_S",
           "LOST_SETTLE_S", "MOVE_TIMEOUT_S", "MUST_DROP", "PLACEHOLDERS", "QUERY_WAIT_S", "RTL_HOLD_S", "RTL_SEEN_S",
           "SETTLE_S", "STARTUP_WAIT_S", "WORLDS", "FakeFleet", "FakeRobot", "Misbehaviour", "MissionRun", "Observed",
           "Shutter", "Site", "UavOptions", "error_lines", "free_udp_port", "junk", "plan_problem", "run_mission",
           "run_stranded", "start_process", "step_ok", "uav_command"]
