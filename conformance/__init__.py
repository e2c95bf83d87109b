"""A harness that plays hub, UAV and world around a robot implementation under test.

The robot conformance suite (the `test_robot_*.py` files beside this one) uses
it to check any robot that speaks the protocol, started from a command line; our
own tests use it to drive the real world and robots. Everything here talks
only through `protocol` (Zenoh on loopback), never through robot internals.
The UAV suite's harness is `conformance.uav_harness`.
"""
from __future__ import annotations

from .fake_uav import FakeUav
from .fake_world import FakeWorld
from .hub import Hub, free_endpoint
from .processes import (DEFAULT_POOL_CMD, DEFAULT_ROBOT_CMD, REPO, robot_command, signal_group, start_robot,
                        stop_process)
from .waiter import Waiter
from .wire import Wire

__all__ = ["DEFAULT_POOL_CMD", "DEFAULT_ROBOT_CMD", "REPO", "FakeUav", "FakeWorld", "Hub", "Waiter", "Wire",
           "free_endpoint", "robot_command", "signal_group", "start_robot", "stop_process"]
