"""The live view, the recording, the replay and report.html, with real processes and a real browser."""
import json
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from scenarios.maps import place, resolve_map
from uav_agent.report import load_report
from uav_robots.record import replay
from uav_robots.record.recording import Recording, read_mcap
from uav_robots.record.report_html import arrived_per_tick, compare
from browser_page import DRAWN, PAGE_RGB, launch, movers_at, open_page, playwright_session

CLI = [sys.executable, "-m", "uav_robots"]
FOXGLOVE = {"/uav/camera": "foxglove.CompressedImage", "/uav/pose": "foxglove.PoseInFrame", "/map": "foxglove.Grid"}
PROTOCOL = {"/fleet/plan": "Plan", "/fleet/tick": "Tick", "/fleet/state": "RobotState", "/fleet/done": "Done",
            "/mission/status": "MissionStatus", "/mission/end": "MissionEnd"}


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _final_cells(report) -> dict[str, list[int]]:
    return {rid: list(cells[-1]) for rid, cells in report["executed"].items()}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """One small mission with --out: its directory and its whole report."""
    out = tmp_path_factory.mktemp("recorded")
    res = subprocess.run(CLI + ["run", "--camera", "ideal", "--robots", "8", "--out", str(out)], capture_output=True,
                         text=True, timeout=240)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    return out, load_report(out)


@pytest.mark.slow
@pytest.mark.process
def test_mission_mcap_holds_the_mission(recorded):
    from mcap.reader import make_reader

    out, report = recorded
    with open(out / "mission.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    topics = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
    for topic, name in {**FOXGLOVE, **PROTOCOL}.items():
        assert topic in topics, f"{topic} missing from mission.mcap"
        assert topics[topic].name == name and topics[topic].encoding == "jsonschema"
        json.loads(topics[topic].data)   # every channel's schema is a JSON schema
    counts = {summary.channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}
    assert counts["/fleet/tick"] == report["ticks"]
    assert counts["/fleet/plan"] == report["robots"]
    assert counts["/fleet/done"] == report["robots"]
    assert counts["/uav/camera"] >= 2   # the survey and the verification at least
    rec = read_mcap(out / "mission.mcap")
    # The vehicle's pose feed, not one pose per image: several a second from take-off to landing.
    times = [ns for ns, _ in rec.poses]
    flight_s = (times[-1] - times[0]) / 1e9
    assert counts["/uav/pose"] > counts["/uav/camera"] and counts["/uav/pose"] >= 10, counts
    assert counts["/uav/pose"] / flight_s >= 3.0, f"{counts['/uav/pose']} poses in {flight_s:.1f} s"
    # While it climbs and flies to its survey pose it is seen moving (the images alone show two places):
    # several distinct positions between take-off and perception, from low down up to the survey height.
    # The UAV waited for the recorder (--observers 1): every status is there, from the first.
    assert [phase for _, phase in rec.phases][:2] == ["connecting", "takeoff"], rec.phases[:3]
    start = next(ns for ns, phase in rec.phases if phase == "takeoff")
    seen = next(ns for ns, phase in rec.phases if phase == "perceive")
    flying = [p for ns, p in rec.poses if start <= ns <= seen]
    assert len({(round(p["east_m"], 2), round(p["north_m"], 2), round(p["alt_m"], 2)) for p in flying}) >= 3, flying
    top = report["uav"]["max_altitude_m"]
    assert min(p["alt_m"] for p in flying) < top / 2 and max(p["alt_m"] for p in flying) >= top - 0.5, flying
    # One state per robot per tick, and the last one is where the world says each robot ended.
    assert counts["/fleet/state"] == report["robots"] * report["ticks"]
    assert {str(r): list(c[max(c)]) for r, c in rec.cells.items()} == _final_cells(report)
    assert rec.ticks == report["ticks"]
    truth = np.array([[c != "@" for c in row] for row in report["truth"]["rows"]])
    assert np.array_equal(rec.free, truth)
    assert rec.end == {"completed": True, "reason": report["reason"]}
    jpeg = cv2.imdecode(np.frombuffer(rec.images[-1][1], np.uint8), cv2.IMREAD_COLOR)
    assert jpeg is not None and max(jpeg.shape[:2]) <= 640


@pytest.mark.slow
@pytest.mark.process
def test_replay_reproduces_the_video(recorded):
    out, report = recorded
    first = out / "replay.mp4"
    kept = out / "first.mp4"
    shutil.copy(first, kept)
    res = subprocess.run(CLI + ["replay", str(out)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    frames_a, frames_b = _frames(kept), _frames(first)
    assert len(frames_a) == len(frames_b) == report["ticks"] + 1
    assert all(np.array_equal(a, b) for a, b in zip(frames_a, frames_b))


def _frames(path: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, f = cap.read()
        if not ok:
            return frames
        frames.append(f)


@pytest.mark.slow
@pytest.mark.process
def test_report_html_has_the_reports_numbers(recorded):
    out, report = recorded
    page = (out / "report.html").read_text()
    assert "<svg" in page and "http" not in page.replace("http-equiv", "")   # self-contained
    metrics = report["plan"]["metrics"]
    rows = compare(report)
    for number in (report["ticks"], report["robots"], metrics["makespan"], metrics["sum_of_costs"],
                   sum(c.executed for c in rows)):
        assert f"<td>{number}</td>" in page
    assert arrived_per_tick(report)[-1] == report["robots"]
    for phase, seconds in report["timings"].items():
        if phase != "wall_total" and seconds > 0:
            assert f"{phase} {seconds:.2f} s" in page


def test_video_is_readable_on_the_450_map(tmp_path):
    """50 robots spread over warehouse-450: discs of at least 7 px with their ids, a frame of bounded size."""
    _, free = resolve_map("warehouse-450", 0)
    p = place(free, 50, 0)
    rec = Recording(free, cells={i: {0: tuple(s), 1: tuple(s)} for i, s in enumerate(p.starts)},
                    goals=dict(enumerate(map(tuple, p.goals))), ticks=1)
    (box, s, r), = [replay.layout(rec)]
    assert r >= replay.MIN_RADIUS_PX
    frames, w, h = replay.render(rec, tmp_path / "v.mp4")
    assert frames == 2 and w <= replay.MAX_SIDE_PX + replay.LEGEND_PX + 2 * r + 8 and h <= w
    frame = _frames(tmp_path / "v.mp4")[-1]
    # A robot's disc: its colour fills a radius-r neighbourhood of its centre (robot 0 here).
    x0, y0 = box[0], box[1]
    pad = r + 2
    cx, cy = (p.starts[0][0] - x0) * s + s // 2 + pad, (p.starts[0][1] - y0) * s + s // 2 + pad
    ring = frame[cy - r + 2, cx].astype(int)
    floor = np.array(replay.FLOOR)
    assert np.abs(ring - floor).sum() > 60, "no disc drawn where robot 0 stands"


@pytest.mark.process
def test_replay_bad_input_is_one_line_exit_2(tmp_path):
    res = subprocess.run(CLI + ["replay", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "mission.mcap" in res.stderr
    (tmp_path / "mission.mcap").write_bytes(b"not an mcap file")
    res = subprocess.run(CLI + ["replay", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    res = subprocess.run(CLI + ["run", "--view", "70000"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and "--view" in res.stderr


def _wait(page, expression, timeout_s):
    page.wait_for_function(expression, timeout=timeout_s * 1000)


@pytest.mark.browser
@pytest.mark.process
def test_live_view_in_a_real_browser(tmp_path):
    port = _port()
    log = open(tmp_path / "run.txt", "w")
    # 5 ticks a second, so two looks a second apart see robots move; people, a forklift and a pallet
    # among them, for the view to draw.
    proc = subprocess.Popen(CLI + ["run", "--camera", "ideal", "--robots", "8", "--tick-rate", "5", "--out", str(tmp_path / "out"),
                                   "--scene", "people=2,forklifts=1,pallets=1", "--view", str(port), "--view-hold", "60"],
                            stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    try:
        with playwright_session() as pw:
            browser = launch(pw)
            try:
                page = open_page(browser.new_page(viewport={"width": 1300, "height": 950}), port, "the view")
                _wait(page, "window.viewState && window.viewState.tick >= 1", 120)
                first = page.evaluate("JSON.stringify(window.viewState.robots)")
                time.sleep(1.0)
                second = page.evaluate("JSON.stringify(window.viewState.robots)")
                assert first != second, "robots did not move between two looks a second apart"
                _wait(page, "window.viewState.end !== null", 120)
                _wait(page, "document.getElementById('camera').naturalWidth > 0", 10)
                # The UAV lands after the mission's end: its pose feed shows it coming down.
                _wait(page, "window.viewState.pose.alt_m !== undefined && window.viewState.pose.alt_m < 1.0", 60)
                time.sleep(0.5)                      # a frame drawn with the last delta
                shown, drawn = page.evaluate("window.viewState"), page.evaluate(DRAWN)
                assert page.inner_text("#end").startswith("completed")
                assert page.inner_text("#movers").startswith("movers on the floor: 4 (2 people, 1 forklift, 1 pallet")
                assert page.is_visible("#moverKey")
                assert len(drawn) >= 3 and all(rgb == PAGE_RGB[kind] for _, kind, rgb in drawn), drawn
                # The report is complete once the launcher has written report.html (it then holds the view).
                deadline = time.monotonic() + 60
                while not (tmp_path / "out" / "report.html").exists():
                    assert time.monotonic() < deadline and proc.poll() is None, (tmp_path / "run.txt").read_text()
                    time.sleep(0.2)
                report = load_report(tmp_path / "out")
                assert shown["movers"] == movers_at(report, report["ticks"])   # the world's last tick, as recorded
                _replayed_movers(browser, tmp_path / "out", report)
            finally:
                browser.close()
        assert {rid: c[:2] for rid, c in shown["robots"].items()} == _final_cells(report)
        assert shown["tick"] == report["ticks"]
        assert shown["end"]["completed"] is report["completed"]
        # The drone was drawn from its pose feed, moving: many poses, several distinct positions.
        assert shown["poses"] >= 10 and len(shown["track"]) >= 3, (shown["poses"], shown["track"])
        assert "live view at http://127.0.0.1:" in (tmp_path / "run.txt").read_text()
    finally:
        _stop(proc)
        log.close()


def _stop(proc) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=5)


def _replayed_movers(browser, out, report) -> None:
    """The recorded mission in the replay view: the movers per tick from the world's record, the
    report's robot-mover counts."""
    port = _port()
    proc = subprocess.Popen(CLI + ["replay", str(out), "--view", str(port), "--view-hold", "60"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    try:
        page = open_page(browser.new_page(), port, "the replay view")
        _wait(page, "window.viewState.updates > 0", 30)
        assert page.evaluate("window.viewState.movers") == movers_at(report, 0)
        page.click("#play")
        _wait(page, f"window.viewState.tick === {report['ticks']}", 30)
        assert page.evaluate("window.viewState.movers") == movers_at(report, report["ticks"])
        assert page.evaluate("window.viewState.moversOutcome") == {
            "movers": 4, "collisions": report["mover_collisions"], "near_misses": report["near_misses"]}
        assert f"near misses {report['near_misses']}" in page.inner_text("#movers")
    finally:
        _stop(proc)


@pytest.mark.browser
@pytest.mark.process
def test_recorded_mission_in_the_view(recorded):
    out, report = recorded
    port = _port()
    proc = subprocess.Popen(CLI + ["replay", str(out), "--view", str(port), "--view-hold", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    try:
        with playwright_session() as pw:
            browser = launch(pw)
            try:
                page = open_page(browser.new_page(), port, "the replay view")
                _wait(page, "window.viewState.updates > 0", 30)
                start = page.evaluate("window.viewState.robots")
                assert {r: c[:2] for r, c in start.items()} == {
                    str(r["id"]): r["start"] for r in report["plan"]["robots"]}
                page.click("#play")
                _wait(page, f"window.viewState.tick === {report['ticks']}", 30)
                assert {r: c[:2] for r, c in page.evaluate("window.viewState.robots").items()} == _final_cells(report)
            finally:
                browser.close()
    finally:
        _stop(proc)


def test_a_view_client_gets_what_changed_since_its_last_update():
    from protocol.codec import encode
    from protocol.keys import Keys
    from protocol.messages import MissionEvent, Plan, RobotState
    from uav_robots.view.state import FleetView, Seen

    k, view = Keys("f1"), FleetView()
    for rid, (a, b) in enumerate([((1, 1), (3, 1)), ((5, 5), (5, 6))]):
        view.apply(k.plan(rid), encode(Plan(robot=rid, plan_id="p", path=[a, b], goal=b)))
    fast, slow = Seen(), Seen()
    first = view.delta(fast)
    assert first["robots"] == {"0": [1, 1, "planned"], "1": [5, 5, "planned"]} and "paths" in first
    assert view.delta(slow)["goals"] == {"0": [3, 1], "1": [5, 6]}
    view.apply(k.state(0), encode(RobotState(robot=0, tick=1, cell=(2, 1), status="stepping")))
    assert view.delta(fast)["robots"] == {"0": [2, 1, "stepping"]}
    assert view.delta(fast).get("robots") is None          # nothing moved since
    view.apply(k.state(0), encode(RobotState(robot=0, tick=2, cell=(3, 1), status="done")))
    view.apply(k.mission_event, encode(MissionEvent(tick=2, time_s=1.0, kind="replan", robots=[1], what="w")))
    # The slow client skipped tick 1: it gets the newest cell only, and the event once.
    late = view.delta(slow)
    assert late["robots"] == {"0": [3, 1, "done"]} and late["tick"] == 2
    assert [e["kind"] for e in late["events"]] == ["replan"] and "events" not in view.delta(slow)
    view.apply(k.state(1), b"not json")                       # a view shows what it can read
    assert view.delta(slow).get("robots") is None


def test_the_view_moves_the_drone_with_its_pose_feed():
    from protocol.codec import encode
    from protocol.keys import Keys
    from protocol.messages import CameraFrame, VehiclePose
    from uav_robots.view.state import FleetView, Seen

    k, view, seen = Keys("f1"), FleetView(), Seen()
    frame = CameraFrame(width=2, height=2, fx=1.0, fy=1.0, cx=1.0, cy=1.0, north_m=-1.0, east_m=1.0, down_m=-5.0,
                        yaw_rad=0.0, time_s=0.0, png=b"x", encoding="jpeg")
    view.apply(k.uav_frame, encode(frame))     # an older UAV: the image's pose is all there is
    assert view.delta(seen)["pose"] == {"east_m": 1.0, "north_m": -1.0, "alt_m": 5.0}
    for i in range(3):
        view.apply(k.uav_pose, encode(VehiclePose(time_s=i * 0.2, north_m=-2.0 - i, east_m=3.0, down_m=-6.0,
                                                  yaw_rad=0.5, armed=True, in_air=True, mode="HOLD")))
    d = view.delta(seen)
    assert d["poses"] == 3 and d["pose"]["north_m"] == -4.0 and d["pose"]["alt_m"] == 6.0
    view.apply(k.uav_frame, encode(frame))     # once fed, an image no longer moves the drone back
    assert view.delta(seen)["pose"]["north_m"] == -4.0
    view.apply(k.uav_pose, b"not a pose")      # a view shows what it can read
    assert view.delta(seen)["poses"] == 3


def test_the_view_survives_fleet_messages_of_the_wrong_shape():
    from uav_robots.view.state import FleetView

    view = FleetView()
    for payload in (b'{"tick": 1}', b"[1, 2]", b'{"robot": 1, "cell": 5, "tick": 1}', b'"text"'):
        view.apply("uavr/f/robot/1/state", payload)
        view.apply("uavr/f/robots/0-3/states", payload)
    view.apply("uavr/f/robot/1/state", b'{"robot": 1, "cell": [2, 3], "tick": 4, "status": "stepping"}')
    assert view.robots == {1: (2, 3, "stepping")} and view.tick == 4
