"""Stops that keep the evidence: whatever ends a run (a dead world, a killed UAV, SIGTERM or Ctrl-C to the
launcher, a full disk), OUT holds this run's report.json and every process's log, within seconds; an earlier
run's outputs never stand as the new run's; one forged tick never costs a long video. Real processes."""
from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest

from protocol.codec import encode
from protocol.keys import Keys
from protocol.messages import Plan, RobotState, Tick

CLI = [sys.executable, "-m", "uav_robots"]
# Slow enough ticks to act mid-execution; the ideal camera, as the subject is not perception.
MISSION = ["run", "--robots", "4", "--camera", "ideal", "--tick-rate", "5"]


class Run:
    """`uav-robots run` in a session of its own, its stdout read line by line as it comes."""

    def __init__(self, out: Path, *extra: str) -> None:
        self.proc = subprocess.Popen(CLI + MISSION + ["--out", str(out), *extra], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, start_new_session=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        self.err = ""
        threading.Thread(target=self._read, daemon=True).start()
        self._err_reader = threading.Thread(target=self._read_err, daemon=True)
        self._err_reader.start()
        self.fleet = self.wait_for("fleet ", 60).split("fleet ")[1].split(",")[0]
        self.endpoint = self.seen[-1].split("zenoh ")[1].split(",")[0]

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.put(line)

    def _read_err(self) -> None:
        self.err = self.proc.stderr.read()

    def wait_for(self, text: str, timeout: float) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                assert self.proc.poll() is None, f"the run ended ({self.proc.returncode}) before {text!r}: {self.err}"
                continue
            self.seen.append(line)
            if text in line:
                return line
        raise AssertionError(f"no {text!r} within {timeout} s: {''.join(self.seen[-5:])}")

    def child(self, module: str) -> int:
        """The pid of the launcher's child `python -m module`."""
        for p in psutil.Process(self.proc.pid).children():
            try:
                args = p.cmdline()
            except psutil.Error:
                continue
            if "-m" in args and args[args.index("-m") + 1:args.index("-m") + 2] == [module]:
                return p.pid
        raise AssertionError(f"no {module} process")

    def wait(self, timeout: float) -> int:
        code = self.proc.wait(timeout=timeout)
        self._err_reader.join(5)
        return code

    def kill(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)   # its children die with it (PR_SET_PDEATHSIG)
            self.proc.wait(timeout=10)


def _report(out: Path) -> dict:
    return json.loads((out / "report.json").read_text())


def _logs(out: Path) -> set[str]:
    return {p.name for p in (out / "logs").glob("*.log") if p.stat().st_size > 0}


EVERY_LOG = {"uav.log", "world.log", "vehicle.log", "robots-0-0.log", "robots-1-1.log", "robots-2-2.log", "robots-3-3.log"}


@pytest.mark.slow
@pytest.mark.parametrize("how, code", [("kill-world", 1), ("kill-uav", 1), ("sigterm", 143), ("sigint", 130)])
@pytest.mark.process
def test_every_stop_mid_execution_leaves_a_report_and_every_log(tmp_path, how, code):
    run = Run(tmp_path)
    try:
        run.wait_for("tick 2/", 60)
        t0 = time.monotonic()
        if how == "kill-world":
            os.kill(run.child("sim_world"), signal.SIGKILL)
        elif how == "kill-uav":
            os.kill(run.child("uav_agent"), signal.SIGKILL)
        else:
            run.proc.send_signal(signal.SIGTERM if how == "sigterm" else signal.SIGINT)
        assert run.wait(40) == code, run.err[-2000:]
        stopped_in = time.monotonic() - t0
    finally:
        run.kill()
    assert _logs(tmp_path) == EVERY_LOG, _logs(tmp_path)
    assert "tick 2/" in (tmp_path / "logs" / "uav.log").read_text(), "the UAV's own lines are in its log"
    report = _report(tmp_path)
    assert report["fleet"] == run.fleet and report["completed"] is False and report["reason"], report
    assert report["exit_codes"]["uav"] is not None, report["exit_codes"]
    assert (tmp_path / "mission.mcap").stat().st_size > 0, "the recording so far"
    if how == "kill-uav":   # it wrote nothing: the launcher's own report says so
        assert report["written_by"] == "launcher" and report["outcome"] == "aborted"
        assert report["reason"].startswith("the UAV exited with code -9 without a report"), report["reason"]
        assert "the launcher wrote" in run.err
        # the vehicle, a process of its own, is left in the air: told to stop, it lands first
        said = (tmp_path / "logs" / "vehicle.log").read_text()
        assert "landing first" in said and "vehicle: stopped; armed False, ON_GROUND" in said, said[-1500:]
    if how == "kill-world":
        assert report["stopped_by"] == "the world process exited with code -9"
        # the UAV noticed the world's token vanish before the launcher's grace ran out: its own words
        assert report.get("written_by") != "launcher" and "the world went away" in report["reason"], report["reason"]
    if how in ("sigterm", "sigint"):   # the launcher stops the UAV with SIGTERM; it writes its own report
        assert report.get("written_by") != "launcher" and report["reason"] == "stopped by SIGTERM", report["reason"]
        assert report["uav"]["landed"] is True
    assert "Traceback" not in run.err, run.err[-3000:]
    assert stopped_in < 25, f"{how}: stopped in {stopped_in:.1f} s"
    assert not list(tmp_path.glob(".partial-*")) and not (tmp_path / ".replay-draft.mp4").exists()


@pytest.mark.slow
@pytest.mark.process
def test_a_failing_run_into_an_earlier_runs_directory_leaves_nothing_of_it_standing(tmp_path):
    """An earlier run's report (8/8 completed) must not become the new run's, nor its page, recording,
    video, details or logs."""
    earlier = {"format": "uav-robots-report/1", "completed": True, "outcome": "completed", "fleet": "earlier",
               "robots": 8, "reason": "", "timings": {}}
    (tmp_path / "report.json").write_text(json.dumps(earlier))
    for name in ("report.html", "details.json", "plan.json", "mission.mcap", "replay.mp4", "overhead.png",
                 "paths.png", "replay.gif"):
        (tmp_path / name).write_text("EARLIER RUN")
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "robots-7-7.log").write_text("EARLIER RUN")
    run = Run(tmp_path)
    try:
        run.wait_for("tick 2/", 60)
        os.kill(run.child("uav_agent"), signal.SIGKILL)
        assert run.wait(40) == 1, run.err[-2000:]
    finally:
        run.kill()
    assert "removed the earlier run's outputs" in run.err
    report = _report(tmp_path)
    assert report["fleet"] == run.fleet and report["completed"] is False, report
    for path in [*tmp_path.iterdir(), *(tmp_path / "logs").iterdir()]:
        assert not path.is_file() or b"EARLIER RUN" not in path.read_bytes(), path
    assert _logs(tmp_path) == EVERY_LOG
    assert "8/8" not in (tmp_path / "report.html").read_text() and run.fleet in (tmp_path / "report.json").read_text()


def _frames(video: Path) -> int:
    import cv2

    cap = cv2.VideoCapture(str(video))
    try:
        return int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()


@pytest.mark.slow
@pytest.mark.process
def test_a_forged_tick_during_a_mission_costs_no_long_video(tmp_path):
    """One decodable Tick(k=100000) and RobotState(tick=100000) on the fleet's keys, then the mission ends:
    the launcher's video (drawn ahead or at the end) stops at the mission's last tick, and says what it left out."""
    from protocol.transport import open_session

    run = Run(tmp_path)
    session = None
    try:
        session = open_session("forger", connect=[run.endpoint], wait_s=20)
        keys = Keys(run.fleet)
        run.wait_for("verify", 60)    # after the last tick, before the landing (the draft video's start)
        session.put(keys.tick, encode(Tick(k=100000, ticks=100000, plan_id="forged")))
        session.put(keys.state(1), encode(RobotState(robot=1, tick=100000, cell=(1, 1), status="stepping")))
        code = run.wait(60)
    finally:
        if session is not None:
            session.close()
        run.kill()
    assert code in (0, 1, 3), run.err[-2000:]      # the subject is the video, not what robots make of a forged tick
    report = _report(tmp_path)
    assert _frames(tmp_path / "replay.mp4") == report["ticks"] + 1
    assert f"message(s) claiming a tick after the mission's last ({report['ticks']}" in run.err, run.err[-2000:]


def _forged_recording(out: Path, with_report: bool) -> None:
    from uav_robots.record.observer import Sample
    from uav_robots.record.recording import write_mcap

    keys = Keys("forged")
    t = time.time_ns()
    samples = [Sample(t, keys.plan(0), encode(Plan(robot=0, plan_id="p", path=[(0, 0), (1, 0), (2, 0), (3, 0)],
                                                 goal=(3, 0))))]
    for k in (1, 2, 3):
        samples += [Sample(t + 10 * k, keys.tick, encode(Tick(k=k, ticks=3, plan_id="p"))),
                    Sample(t + 10 * k + 1, keys.state(0), encode(RobotState(robot=0, tick=k, cell=(k, 0),
                                                                             status="stepping", plan_id="p")))]
    samples += [Sample(t + 50, keys.tick, encode(Tick(k=100000, ticks=100000, plan_id="p"))),
                Sample(t + 51, keys.state(0), encode(RobotState(robot=0, tick=100000, cell=(3, 0), status="done")))]
    write_mcap(out / "mission.mcap", samples, keys.prefix, ["....", "...."], 1.0)
    if with_report:
        (out / "report.json").write_text(json.dumps({"fleet": "forged", "ticks": 3, "completed": True}))


@pytest.mark.parametrize("with_report", [True, False])
@pytest.mark.process
def test_replay_draws_up_to_the_missions_last_tick_whatever_a_message_claims(tmp_path, with_report):
    _forged_recording(tmp_path, with_report)
    res = subprocess.run(CLI + ["replay", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "4 frames" in res.stdout and _frames(tmp_path / "replay.mp4") == 4, res.stdout
    assert "2 message(s) claiming a tick after the mission's last (3" in res.stderr, res.stderr


def test_the_launchers_views_are_bounded_by_the_report(tmp_path):
    """write_views as the launcher calls it after a mission: the video stops at the report's ticks."""
    from uav_robots.record.after_mission import write_views
    from uav_robots.record.observer import Sample
    from uav_robots.record.recording import read_mcap

    keys = Keys("forged")
    samples = [Sample(1, keys.plan(0), encode(Plan(robot=0, plan_id="p", path=[(0, 0), (1, 0)], goal=(1, 0)))),
               Sample(2, keys.tick, encode(Tick(k=1, ticks=1, plan_id="p"))),
               Sample(3, keys.tick, encode(Tick(k=100000, ticks=100000, plan_id="p")))]
    (tmp_path / "report.json").write_text(json.dumps({"fleet": "forged", "ticks": 1, "completed": True}))
    assert write_views(tmp_path, samples, "forged", ["....", "...."], quiet=True) == []
    assert _frames(tmp_path / "replay.mp4") == 2 and (tmp_path / "report.html").exists()
    assert read_mcap(tmp_path / "mission.mcap").ticks == 100000, "the recording keeps what came, as it came"


def test_report_json_is_written_whole_or_not_at_all(tmp_path):
    from uav_robots.common.outputs import write_atomic

    path = tmp_path / "report.json"
    write_atomic(path, '{"a": 1}')
    with pytest.raises(UnicodeEncodeError):
        write_atomic(path, '{"a": "\ud800"}')       # fails half way, as a full disk does
    assert path.read_text() == '{"a": 1}' and [p.name for p in tmp_path.iterdir()] == ["report.json"]


def test_a_touchdown_faster_than_3_m_s_is_a_crash_in_the_vehicles_record():
    """The vehicle's own record says it hit the ground, with the speed, whether it fell or was flown down."""
    from sim_world.vehicle.dynamics import Dynamics
    from sim_world.vehicle.motion import Setpoint
    from sim_world.vehicle.journal import Journal

    class Pilot:
        def __init__(self, down_m: float | None, speed_down: float = 0.0) -> None:
            self.down, self.speed_down = down_m, speed_down

        def setpoint(self, dt, wall_now):
            return None if self.down is None else Setpoint((0.0, 0.0, self.down), 0.0, 5.0, 5.0, self.speed_down)

        def on_moved(self, setpoint):
            pass

        def on_contact(self, contact):
            pass

    lock = threading.RLock()
    clock = [0.0]
    journal = Journal(lock, lambda: clock[0])
    dyn = Dynamics(lock, journal, lambda: 120.0)

    def fly(pilot: Pilot, dt: float = 0.2) -> list[str]:
        while dyn.altitude < 19.9:
            dyn.step(dt, 0.0, Pilot(-20.0, 5.0))
        before = len(journal.events)
        for _ in range(500):
            dyn.step(dt, 0.0, pilot)
        return [text for _, text in journal.events[before:]]

    assert fly(Pilot(5.0, 15.9)) == ["hit the ground at 15.9 m/s (a crash: over 3 m/s)", "landed"]   # flown in
    assert fly(Pilot(None))[0].startswith("hit the ground at 20.0 m/s")                             # fell
    assert fly(Pilot(5.0, 0.7)) == ["landed"]                                                       # landed


@pytest.mark.slow
@pytest.mark.skipif(os.geteuid() != 0 or not shutil.which("mount"), reason="mounts a small tmpfs (root)")
@pytest.mark.process
def test_a_full_disk_is_one_line_exit_1_and_no_hang(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)]).returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        (disk / "filler").write_bytes(b"\0" * (2048 - 40) * 1024)    # 40 KB left: logs fit, images do not
        res = subprocess.run(CLI + MISSION[:5] + ["--quiet", "--out", str(disk / "out")], capture_output=True,
                             text=True, timeout=90)
        assert res.returncode == 1, res.stderr[-2000:]
        said = [line for line in res.stderr.splitlines() if line.startswith("uav-robots: could not write ")]
        assert len(said) == 1 and "(No space left on device)" in said[0], res.stderr[-2000:]
        report = disk / "out" / "report.json"
        assert not report.exists() or json.loads(report.read_text()), "never half a report"
        assert not list((disk / "out").glob(".partial-*"))
    finally:
        subprocess.run(["umount", "-l", str(disk)])


def test_the_draft_video_stops_at_the_plans_last_tick_and_is_kept_only_for_the_same_bound(tmp_path):
    import numpy as np

    from protocol.mapfile import format_rows
    from protocol.messages import MissionStatus
    from uav_robots.record.observer import Sample
    from uav_robots.record.video_ahead import VideoAhead

    class Feed:
        def __init__(self, samples):
            self.samples = samples

        def since(self, i):
            return self.samples[i:]

    keys, free = Keys("f1"), np.ones((2, 4), bool)
    feed = Feed([Sample(1, keys.plan(0), encode(Plan(robot=0, plan_id="p", path=[(0, 0), (1, 0), (2, 0)],
                                                     goal=(2, 0)))),
                 Sample(2, keys.tick, encode(Tick(k=1, ticks=2, plan_id="p"))),
                 Sample(3, keys.tick, encode(Tick(k=100000, ticks=100000, plan_id="p"))),
                 Sample(4, keys.mission_status, encode(MissionStatus(phase="land")))])
    ahead = VideoAhead(feed, tmp_path, "f1", free)
    ahead.poll()
    assert ahead._finish(), "the draft is drawn, and soon"
    assert not ahead.take(feed.samples, format_rows(free), tmp_path / "other.mp4", 7), "another bound: drawn again"
    ahead = VideoAhead(feed, tmp_path, "f1", free)
    ahead.poll()
    assert ahead.take(feed.samples, format_rows(free), tmp_path / "replay.mp4", 2)
    assert _frames(tmp_path / "replay.mp4") == 2      # ticks 0 and 1: the forged tick is left out


@pytest.mark.process
def test_a_uav_deaf_to_sigterm_is_killed_after_the_bound_or_at_a_second_signal(tmp_path, monkeypatch):
    """The stop is bounded: UAV_STOP_S after SIGTERM the UAV is killed; a second Ctrl-C stops waiting."""
    from uav_robots.run import launcher as launcher_module
    from uav_robots.cli import build_parser
    from uav_robots.run.launcher import Child, Launcher

    deaf = ("import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); "
            "time.sleep(120)")
    for hurry in (False, True):
        monkeypatch.setattr(launcher_module, "UAV_STOP_S", 30.0 if hurry else 1.0)
        lau = Launcher(build_parser(["run"]).parse_args(["run", "--out", str(tmp_path / str(hurry))]))
        uav = subprocess.Popen([sys.executable, "-c", deaf], stdout=subprocess.PIPE, text=True)
        try:
            assert uav.stdout.readline() == "up\n"
            lau.children.append(Child("uav", uav, None))
            if hurry:
                lau.on_signal(signal.SIGINT, None)
                lau.stopping = True
                threading.Timer(0.5, lau.on_signal, (signal.SIGINT, None)).start()
            t0 = time.monotonic()
            lau.stop(graceful=False)
            assert uav.poll() == -signal.SIGKILL and time.monotonic() - t0 < 10
        finally:
            if uav.poll() is None:
                uav.kill()
            uav.wait(5)
