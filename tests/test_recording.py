"""mission.mcap from what the observer heard: garbage on a fleet key is left out, never the end of the recording."""
from __future__ import annotations

import time

from protocol.keys import Keys
from protocol.messages import Plan, Tick, encode
from uav_robots.observer import Sample
from uav_robots.recording import read_mcap, write_mcap


def test_garbage_or_forged_bytes_on_fleet_keys_are_left_out_and_the_rest_is_replayable(tmp_path):
    keys = Keys("f1")
    t = time.time_ns()
    good = [Sample(t, keys.plan(3), encode(Plan(robot=3, plan_id="p", path=[(0, 0), (1, 0)], goal=(1, 0)))),
            Sample(t + 1, keys.tick, encode(Tick(k=1, ticks=1, plan_id="p")))]
    bad = [Sample(t + 2, keys.tick, b"\xff\x00garbage"),
           Sample(t + 3, keys.tick, b'{"type":"Tick","v":1,"k":"one"}'),        # valid JSON, not a Tick
           Sample(t + 4, keys.plan(3), b'{"robot":3}'),
           Sample(t + 5, keys.mission_status, b"[1, 2")]
    path = tmp_path / "mission.mcap"
    counts = write_mcap(path, good + bad, keys.prefix, [".."], 1.0)
    assert counts == {"/map": 1, "/fleet/plan": 1, "/fleet/tick": 1}
    rec = read_mcap(path)
    assert rec.ticks == 1 and rec.paths == {3: [(0, 0), (1, 0)]} and rec.goals == {3: (1, 0)}
