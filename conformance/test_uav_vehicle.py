"""UAV conformance: its own vehicle, which it must watch (docs/protocol.md, Faults and recovery).

The suite plays router, world and robots around the UAV under test, started from
`--uav-cmd` (conftest.py); a mission is shared by the tests of one module. See
docs/protocol.md, "Conformance", and docs/conformance-rules.md.
"""
from __future__ import annotations

from conformance.uav_harness import Misbehaviour, run_mission
from conformance.uav_steps import fails_with_one_line, fault, no_harness_trouble, ticks_after


def test_a_mode_the_uav_did_not_command_ends_the_mission(uav_options, tmp_path):
    """A ground station commands RTL at tick 2; the fleet holds its states of that tick 2 s more."""
    run = run_mission(uav_options, Misbehaviour(rtl_at=2), tmp_path)
    _, _, k, at = fault(run, "rtl")
    ticked = ticks_after(run, k)
    assert not ticked, f"the UAV put Tick {ticked[0].k} after the vehicle switched to RTL at tick {k}"
    assert [t for t, e in run.log.events if t >= at], "no MissionEvent says the vehicle left the mission's control"
    fails_with_one_line(run, uav_options, at, r"RTL|RETURN|[Rr]eturn|mode", uav_options.abort_s)
    no_harness_trouble(run)
