"""mission.mcap from what the observer heard: garbage on a fleet key is left out, never the end of the recording."""
from __future__ import annotations

import time

from protocol.codec import encode
from protocol.keys import Keys
from protocol.messages import MissionStatus, Plan, RobotState, StateBatch, Tick
from uav_robots.record.observer import Sample
from uav_robots.record.recording import drawn_recording, read_mcap, write_mcap


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


def test_the_video_draft_reads_the_samples_as_the_recording_holds_them(tmp_path):
    """video_ahead draws from the samples directly: the same Recording as writing and reading them."""
    keys = Keys("f1")
    t = time.time_ns()
    rows = ["....", ".@..", "...."]
    samples = [
        Sample(t + 5, keys.state(0), encode(RobotState(robot=0, tick=1, cell=(1, 0), status="stepping", plan_id="p"))),
        Sample(t, keys.plan(0), encode(Plan(robot=0, plan_id="p", path=[(0, 0), (1, 0), (2, 0)], goal=(2, 0)))),
        Sample(t, keys.plan(1), encode(Plan(robot=1, plan_id="p", path=[(3, 2), (3, 1)], goal=(3, 1)))),
        Sample(t + 1, keys.tick, encode(Tick(k=1, ticks=2, plan_id="p"))),
        Sample(t + 5, keys.states_as([1, 2]), encode(StateBatch(tick=1, states=[
            (1, (3, 1), "done", "p", ""), (2, (0, 2), "idle", "", "")]))),
        Sample(t + 6, keys.tick, encode(Tick(k=2, ticks=2, plan_id="p"))),
        Sample(t + 7, keys.state(0), encode(RobotState(robot=0, tick=2, cell=(2, 0), status="done", plan_id="p"))),
        Sample(t + 8, keys.plan(0), encode(Plan(robot=0, plan_id="q", path=[(2, 0)], goal=(2, 0)))),   # a replan
        Sample(t + 9, keys.tick, b'{"type":"Tick","v":1,"k":"one"}'),                       # not a Tick: skipped
        Sample(t + 9, keys.states_as([1]), b"\xff"),
        Sample(t + 3, keys.mission_status, encode(MissionStatus(phase="executing"))),         # not drawn
    ]
    write_mcap(tmp_path / "m.mcap", samples, keys.prefix, rows, 1.0)
    written, direct = read_mcap(tmp_path / "m.mcap"), drawn_recording(samples, keys.prefix, rows)
    assert (direct.free == written.free).all() and direct.free.shape == (3, 4) and not direct.free[1, 1]
    for field in ("cells", "goals", "paths", "starts", "ticks", "tick_times"):
        assert getattr(direct, field) == getattr(written, field), field
    assert direct.cells == {0: {1: (1, 0), 2: (2, 0)}, 1: {1: (3, 1)}, 2: {1: (0, 2)}} and direct.ticks == 2
    assert list(direct.goals.items()) == list(written.goals.items())   # the order goals are drawn in
