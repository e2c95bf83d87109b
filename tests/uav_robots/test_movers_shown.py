"""The world's movers (people, forklifts, pallets) in the live view, mission.mcap, replay.mp4 and report.html
(issue 32): as heard on the wire, and as the world recorded them."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol.codec import encode
from protocol.keys import Keys
from protocol.messages import FloorMovers, MissionStatus, Plan, RobotState, Tick
from uav_robots.record import replay, report_html
from uav_robots.record.observer import Sample
from uav_robots.record.recording import (Recording, bound, drawn_recording, movers_per_tick, read_mcap, take_trace,
                                         write_mcap)
from uav_robots.view.state import FleetView, Seen

CLI = [sys.executable, "-m", "uav_robots"]
ROWS = ["........", ".@@..@@.", "........", ".@@..@@.", "........", "........"]
K = Keys("f1")


def _movers(tick: int, *movers) -> bytes:
    return encode(FloorMovers(tick=tick, movers=list(movers)))


def _mission_samples(t: int) -> list[Sample]:
    """Two robots over three ticks; a person walking, a forklift parked, a pallet dropped at tick 2; the
    world's movers of tick 1 merged into tick 2's (its publisher polls)."""
    return [
        Sample(t, K.plan(0), encode(Plan(robot=0, plan_id="p", path=[(0, 0), (1, 0), (2, 0), (3, 0)], goal=(3, 0)))),
        Sample(t, K.plan(1), encode(Plan(robot=1, plan_id="p", path=[(0, 5), (1, 5), (2, 5), (2, 5)], goal=(2, 5)))),
        Sample(t + 1, K.world_movers, _movers(0, (0, "person", (4, 2)), (1, "forklift", (6, 4)))),
        *(s for k in (1, 2, 3) for s in (
            Sample(t + 10 * k, K.tick, encode(Tick(k=k, ticks=3, plan_id="p"))),
            Sample(t + 10 * k + 1, K.state(0), encode(RobotState(robot=0, tick=k, cell=(k, 0), status="stepping"))),
            Sample(t + 10 * k + 1, K.state(1), encode(RobotState(robot=1, tick=k, cell=(min(k, 2), 5),
                                                                 status="stepping"))))),
        Sample(t + 22, K.world_movers, _movers(2, (0, "person", (4, 4)), (1, "forklift", (6, 4)),
                                               (2, "pallet", (6, 2)))),
        Sample(t + 32, K.world_movers, _movers(3, (0, "person", (5, 4)), (1, "forklift", (6, 4)),
                                               (2, "pallet", (6, 2)))),
        Sample(t + 40, K.mission_status, encode(MissionStatus(phase="land"))),
    ]


def _report(ticks: int = 3) -> dict:
    """report.json of that mission as the world recorded it: every tick's cells, one contact, near misses."""
    return {"outcome": "completed", "robots": 2, "ticks": ticks, "collisions": 1, "mover_collisions": 1,
            "near_misses": 2, "near_miss_ticks": 3, "movers": 3,
            "executed": {"0": [[0, 0], [1, 0], [2, 0], [3, 0]], "1": [[0, 5], [1, 5], [2, 5], [2, 5]]},
            "truth": {"movers": {
                "movers": [{"id": 0, "kind": "person", "appears": 0, "scripted": False},
                           {"id": 1, "kind": "forklift", "appears": 0, "scripted": False},
                           {"id": 2, "kind": "pallet", "appears": 2, "scripted": False}],
                "trace": {"0": [[4, 2], [4, 3], [4, 4], [5, 4]], "1": [[6, 4]] * 4, "2": [[6, 2]] * 4},
                "contacts": [{"tick": 3, "robot": 0, "mover": 0, "cell": [3, 0], "how": "swap"}],
                "near_misses": 2, "near_miss_ticks": 3, "collisions": 1}}}


def test_the_view_sends_the_movers_when_they_moved_and_nothing_on_a_floor_without_them():
    view, fast, slow = FleetView(), Seen(), Seen()
    view.apply(K.state(0), encode(RobotState(robot=0, tick=1, cell=(1, 0), status="stepping")))
    first = view.delta(fast)
    assert "movers" not in first and "movers_outcome" not in first      # a floor as before
    view.apply(K.world_movers, _movers(1, (0, "person", (4, 2)), (1, "forklift", (6, 4))))
    assert view.delta(fast)["movers"] == {"0": ["person", 4, 2], "1": ["forklift", 6, 4]}
    view.apply(K.world_movers, _movers(2, (0, "person", (4, 2)), (1, "forklift", (6, 4))))   # a pause
    assert "movers" not in view.delta(fast)
    view.apply(K.world_movers, _movers(3, (0, "person", (4, 3)), (1, "forklift", (6, 4)), (2, "pallet", (6, 2))))
    view.apply(K.world_movers, _movers(2, (0, "person", (4, 2))))       # overtaken by tick 3's: dropped
    view.apply(K.world_movers, b'{"type":"FloorMovers","v":1,"tick":4,"movers":[[0,"robot",[1,1]]]}')   # no kind
    view.apply(K.world_movers, b"\xff")
    newest = {"0": ["person", 4, 3], "1": ["forklift", 6, 4], "2": ["pallet", 6, 2]}
    assert view.delta(fast)["movers"] == newest
    late = view.delta(slow)       # skipped ticks 1 and 2: the newest only
    assert late["movers"] == newest and "movers" not in view.delta(slow)
    # The counts only the report says, once; a report without movers says nothing.
    view.report({"robots": 2})
    assert "movers_outcome" not in view.delta(fast)
    view.report(_report())
    assert view.delta(fast)["movers_outcome"] == {"movers": 3, "collisions": 1, "near_misses": 2}
    assert "movers_outcome" not in view.delta(fast) and view.delta(slow)["movers_outcome"]["collisions"] == 1


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_observer_hears_the_movers_over_zenoh_for_the_view_and_the_recording(tmp_path, zenoh_endpoint):
    """A world's session on loopback puts FloorMovers; the launcher's observer hears them: the view draws
    them, mission.mcap keeps them on /world/movers with the protocol's schema, each as it came."""
    from mcap.reader import make_reader

    from protocol.transport import open_session
    from uav_robots.record.observer import Observer
    from uav_robots.view.server import Pump

    world = open_session("world", listen=[zenoh_endpoint])
    try:
        observer = Observer(zenoh_endpoint, "f1", wait_s=10)
        time.sleep(0.3)        # the subscription reaches the world's session
        sent = [FloorMovers(tick=k, movers=[(0, "person", (4, 2 + k)), (1, "forklift", (6, 4))]) for k in range(3)]
        for m in sent:
            world.put(K.world_movers, encode(m))
        deadline = time.monotonic() + 10
        while len(observer.since(0)) < len(sent):
            assert time.monotonic() < deadline, f"heard {len(observer.since(0))} of {len(sent)}"
            time.sleep(0.05)
        samples = observer.close()
    finally:
        world.close()
    view = FleetView()
    Pump(lambda i: samples[i:], view).close()
    assert view.delta(Seen())["movers"] == {"0": ["person", 4, 4], "1": ["forklift", 6, 4]}
    counts = write_mcap(tmp_path / "m.mcap", samples, K.prefix, ROWS, 1.0)
    assert counts == {"/map": 1, "/world/movers": 3}
    with open(tmp_path / "m.mcap", "rb") as f:
        reader = make_reader(f)
        schema, channel, _ = next(iter(reader.iter_messages(topics=["/world/movers"])))
        assert schema.name == "FloorMovers" and schema.encoding == "jsonschema" and channel.message_encoding == "json"
        json.loads(schema.data)
        f.seek(0)
        bodies = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/world/movers"])]
    assert [(b["tick"], b["movers"]) for b in bodies] == [
        (m.tick, [[i, kind, list(cell)] for i, kind, cell in m.movers]) for m in sent]


def test_the_recording_keeps_the_movers_as_heard_and_the_draft_reads_them_alike(tmp_path):
    t = time.time_ns()
    samples = _mission_samples(t) + [
        Sample(t + 50, K.world_movers, b"\xff\x00garbage"),
        Sample(t + 51, K.world_movers, b'{"type":"FloorMovers","v":1,"tick":"two","movers":[]}'),
        Sample(t + 52, K.world_movers, _movers(100000, (0, "person", (0, 0))))]    # a forged tick
    counts = write_mcap(tmp_path / "m.mcap", samples, K.prefix, ROWS, 1.0)
    assert counts["/world/movers"] == 4      # tick 0, 2, 3 and the forged one; no garbage
    written, direct = read_mcap(tmp_path / "m.mcap"), drawn_recording(samples, K.prefix, ROWS)
    assert written.movers == direct.movers and sorted(written.movers) == [0, 2, 3, 100000]
    assert written.ticks == 3                # the movers' ticks never lengthen the mission
    assert bound(written, 3) == 1 and sorted(written.movers) == [0, 2, 3]
    per_tick = movers_per_tick(written)
    assert per_tick[1] == per_tick[0] == {0: ("person", (4, 2)), 1: ("forklift", (6, 4))}   # tick 1 merged
    assert per_tick[2][2] == ("pallet", (6, 2)) and per_tick[3][0] == ("person", (5, 4))


def _frames(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    while (got := cap.read())[0]:
        out.append(got[1])
    return out


def _colour_at(frame: np.ndarray, rec: Recording, cell: tuple[int, int]) -> np.ndarray:
    (x0, y0, _, _), s, r = replay.layout(rec)
    pad = r + 2
    return frame[(cell[1] - y0) * s + s // 2 + pad, (cell[0] - x0) * s + s // 2 + pad].astype(int)


def _near(pixel: np.ndarray, bgr) -> bool:
    return int(np.abs(pixel - np.array(bgr)).sum()) < 90      # mp4v's loss, not another colour


def test_replay_draws_each_ticks_movers_from_the_worlds_record(tmp_path):
    rec = read_mcap_of(tmp_path, _mission_samples(time.time_ns()))
    report = _report()
    assert take_trace(rec, report)           # the world's tick 1, which the recording merged
    assert movers_per_tick(rec)[1] == {0: ("person", (4, 3)), 1: ("forklift", (6, 4))}
    assert 2 not in movers_per_tick(rec)[1] and rec.contacts == [3]
    frames, _, _ = replay.render(rec, tmp_path / "v.mp4")
    video = _frames(tmp_path / "v.mp4")
    assert frames == len(video) == 4
    for t, movers in enumerate(movers_per_tick(rec)):
        for kind, cell in movers.values():
            assert _near(_colour_at(video[t], rec, cell), replay.MOVER_BGR[kind]), (t, kind, cell)
    assert not _near(_colour_at(video[1], rec, (6, 2)), replay.MOVER_BGR["pallet"])   # not dropped yet
    # One beyond the region the robots use is counted, not drawn (the video shows that region only).
    report["truth"]["movers"]["movers"].append({"id": 3, "kind": "person", "appears": 0, "scripted": False})
    report["truth"]["movers"]["trace"]["3"] = [[7, 5]] * 4
    take_trace(rec, report)
    assert replay.region(rec)[2] == 7 and replay.render(rec, tmp_path / "w.mp4")[0] == 4
    # The view's replay: each mover's cell per tick, none before it came; the report's counts.
    line = replay.timeline(rec, report)
    assert line["movers"]["2"] == {"kind": "pallet", "cells": [None, None, [6, 2], [6, 2]]}
    assert line["movers"]["0"]["cells"][1] == [4, 3]
    assert line["movers_outcome"] == {"movers": 3, "collisions": 1, "near_misses": 2}
    json.dumps(line)


def read_mcap_of(tmp_path: Path, samples: list[Sample]) -> Recording:
    write_mcap(tmp_path / "m.mcap", samples, K.prefix, ROWS, 1.0)
    return read_mcap(tmp_path / "m.mcap")


def test_a_floor_without_movers_draws_and_reports_as_before(tmp_path):
    samples = [s for s in _mission_samples(time.time_ns()) if s.key != K.world_movers]
    rec = read_mcap_of(tmp_path, samples)
    plain = {k: v for k, v in _report().items() if k not in ("truth", "movers", "mover_collisions", "near_misses",
                                                               "near_miss_ticks")}
    assert not take_trace(rec, plain) and not rec.movers
    assert "movers" not in replay.timeline(rec, plain) and "movers_outcome" not in replay.timeline(rec, plain)
    page = report_html.render(plain)
    assert "mover" not in page.lower() and "People" not in page
    # A trace that does not read leaves the recording as heard.
    assert not take_trace(rec, {"truth": {"movers": {"trace": {"0": "garbage"}}}}) and not rec.movers


def test_report_html_has_the_movers_and_their_contacts():
    page = report_html.render(_report())
    section = page[page.index("<h2>People, forklifts and pallets</h2>"):page.index("<h2>Events</h2>")]
    assert "<td>3 (1 forklift, 1 pallet, 1 person)</td>" in section
    for label, n in (("robot-mover collisions", 1), ("near misses (a robot within one cell of a mover)", 2)):
        assert f"<th>{label}</th><td>{n}</td>" in section
    assert '<table id="mover-contacts">' in section and "<td>3</td><td>0</td><td>0</td><td>3, 0</td><td>swap</td>" in section
    # No contact: no contacts table; never a Python repr.
    calm = _report()
    calm["truth"]["movers"]["contacts"], calm["mover_collisions"] = [], 0
    section = report_html.render(calm)
    assert "mover-contacts" not in section and "[" not in section.split("<h2>People")[1].split("<h2>Events")[0]


@pytest.mark.process
def test_replay_command_draws_the_recorded_movers(tmp_path):
    write_mcap(tmp_path / "mission.mcap", _mission_samples(time.time_ns()), K.prefix, ROWS, 1.0)
    (tmp_path / "report.json").write_text(json.dumps(_report()))
    res = subprocess.run(CLI + ["replay", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "4 frames" in res.stdout and "2 robots, 3 movers" in res.stdout, res.stdout
