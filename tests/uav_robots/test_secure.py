"""Mutual TLS and access control (issue 9, point 5): real Zenoh sessions over TLS on loopback,
with the configs `uav-robots secure init` writes; the router is opened with the UAV's own config."""
from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from protocol.codec import decode, encode
from protocol.errors import MissionError
from protocol.keys import Keys
from protocol.messages import (Done, MissionEnd, MoveRequest, MoveResult, Plan, RobotState, Tick, WorldInfo,
                               WorldInfoRequest)
from protocol.transport import ZenohTransport, open_session
from uav_robots.secure.fleet import make_fleet_dir, new_fleet, read_fleet_dir

REPO = Path(__file__).resolve().parents[2]
WAIT_S = 3.0


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def fleet_dir(tmp_path):
    d = tmp_path / "secure"
    fleet = new_fleet("sec", 3, [[0], [1], [2]], ["127.0.0.1"], _free_port(), d)
    make_fleet_dir(d, fleet)
    return d, fleet


def _open(d: Path, name: str, timeout_ms: int = 3000) -> ZenohTransport:
    return ZenohTransport((d / f"{name}.json5").read_text(), name, {"connect/timeout_ms": timeout_ms})


class Inbox:
    def __init__(self) -> None:
        self.items: list[tuple[str, bytes]] = []
        self.cv = threading.Condition()

    def __call__(self, key: str, payload: bytes) -> None:
        with self.cv:
            self.items.append((key, payload))
            self.cv.notify_all()

    def wait_for(self, pred, timeout: float = WAIT_S) -> bool:
        with self.cv:
            return self.cv.wait_for(lambda: any(pred(k, p) for k, p in self.items), timeout)


def _open_hub(d: Path) -> ZenohTransport:
    """The router with the UAV's config, announcing the UAV as the UAV agent does."""
    hub = _open(d, "uav")
    hub.announce(Keys("sec").alive_uav)
    return hub


def _alive(t: ZenohTransport, key: str) -> bool:
    seen = threading.Event()
    t.watch_alive(key, lambda _k, alive: alive and seen.set())
    return seen.wait(WAIT_S)


@pytest.mark.process
def test_init_writes_private_keys_and_configs_zenoh_accepts(tmp_path):
    out = tmp_path / "s"
    r = subprocess.run([sys.executable, "-m", "uav_robots", "secure", "init", str(out), "--robots", "70",
                        "--fleet", "f1"], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                       env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 0, r.stderr
    fleet = read_fleet_dir(out)
    # 70 robots are hosted as 4 pools, one identity each
    assert [w.name for w in fleet.identities()] == ["uav", "world", "observer", "robots-0-17", "robots-18-35",
                                                     "robots-36-53", "robots-54-69"]
    for w in fleet.identities():
        assert stat.S_IMODE((out / f"{w.name}.key").stat().st_mode) == 0o600
        cfg = json.loads((out / f"{w.name}.json5").read_text())
        assert cfg["transport"]["link"]["tls"]["enable_mtls"] is True
    assert not list(out.glob("ca.key")) and stat.S_IMODE(out.stat().st_mode) == 0o700
    acl = json.loads((out / "uav.json5").read_text())["access_control"]
    assert acl["default_permission"] == "deny"
    assert {s["id"]: s["cert_common_names"] for s in acl["subjects"]}["robots-18-35"] == ["robots-18-35"]
    again = subprocess.run([sys.executable, "-m", "uav_robots", "secure", "init", str(out), "--robots", "2"],
                           capture_output=True, text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert again.returncode == 2 and "not an empty directory" in again.stderr and "Traceback" not in again.stderr


@pytest.mark.slow
def test_a_client_without_a_certificate_cannot_join(fleet_dir):
    d, fleet = fleet_dir
    with _open(d, "uav") as hub:
        hub_inbox = Inbox()
        hub.subscribe(Keys("sec").all_states, hub_inbox)
        no_cert = {"mode": "client", "connect": {"endpoints": [f"tls/127.0.0.1:{fleet.port}"], "timeout_ms": 2000},
                   "scouting": {"multicast": {"enabled": False}},
                   "transport": {"link": {"tls": {"root_ca_certificate": str(d / "ca.pem")}}}}
        t0 = time.monotonic()
        with pytest.raises(MissionError, match="cannot open zenoh session"):
            ZenohTransport(json.dumps(no_cert), "stranger")
        plain = {**no_cert, "connect": {"endpoints": [f"tcp/127.0.0.1:{fleet.port}"], "timeout_ms": 2000},
                 "transport": {}}
        with pytest.raises(MissionError):
            ZenohTransport(json.dumps(plain), "stranger")
        assert time.monotonic() - t0 < 10
        # the door is not simply shut: a fleet member gets in
        with _open(d, "robot-0") as r0:
            r0.put(Keys("sec").state(0), b"x")
            assert hub_inbox.wait_for(lambda k, p: k.endswith("/robot/0/state"))


def test_a_robot_reaches_only_its_own_keys(fleet_dir):
    d, _ = fleet_dir
    k = Keys("sec")
    with _open_hub(d) as hub, _open(d, "robot-0") as r0, _open(d, "robot-1") as r1:
        at_hub, at_r1 = Inbox(), Inbox()
        for key in (k.all_states, k.all_done, k.all_acks, k.tick, k.mission_end):
            hub.subscribe(key, at_hub)
        for key in (k.plan(1), k.tick, k.mission_end):
            r1.subscribe(key, at_r1)
        assert _alive(r1, k.alive_uav) and _alive(r0, k.alive_uav)
        forged = [(k.state(1), RobotState(robot=1, tick=1, cell=(0, 0), plan_id="p", status="error")),
                  (k.done(1), Done(robot=1, tick=1, cell=(0, 0))),
                  (k.tick, Tick(k=100_000, ticks=100_000, plan_id="p")),
                  (k.plan(1), Plan(robot=1, plan_id="forged", start_tick=0, path=[(0, 0), (0, 1)], goal=(0, 1))),
                  (k.mission_end, MissionEnd(completed=True))]
        for key, msg in forged:
            r0.put(key, encode(msg))
        r0.put(k.state(0), encode(RobotState(robot=0, tick=1, cell=(0, 0), plan_id="p", status="moving")))
        # the robot's own state arrives (the link works), and only it
        assert at_hub.wait_for(lambda key, p: key == k.state(0))
        hub.put(k.tick, encode(Tick(k=1, ticks=3, plan_id="p")))
        assert at_r1.wait_for(lambda key, p: key == k.tick and decode(p, Tick).k == 1)
        time.sleep(0.5)
        # the hub hears its own tick (a local delivery), and of robot 0 only robot 0's state
        assert [(key, decode(p, Tick).k if key == k.tick else None) for key, p in at_hub.items] == [
            (k.state(0), None), (k.tick, 1)]
        assert [decode(p, Tick).k for key, p in at_r1.items] == [1]


def test_the_observer_hears_everything_and_can_say_nothing(fleet_dir):
    d, _ = fleet_dir
    k = Keys("sec")
    with _open_hub(d) as hub, _open(d, "robot-0") as r0, _open(d, "observer") as obs:
        at_obs, at_hub, at_r0 = Inbox(), Inbox(), Inbox()
        obs.subscribe(f"{k.prefix}/**", at_obs)
        for key in (k.all_states, k.tick, k.mission_end):
            hub.subscribe(key, at_hub)
        r0.subscribe(k.tick, at_r0)
        assert _alive(r0, k.alive_uav)
        time.sleep(0.5)   # the observer's subscription reaches the router
        obs.put(k.tick, encode(Tick(k=100_000, ticks=100_000, plan_id="p")))
        obs.put(k.state(0), encode(RobotState(robot=0, tick=1, cell=(0, 0), plan_id="p", status="error")))
        obs.put(k.mission_end, encode(MissionEnd(completed=True)))
        hub.put(k.tick, encode(Tick(k=1, ticks=3, plan_id="p")))
        r0.put(k.state(0), encode(RobotState(robot=0, tick=1, cell=(0, 0), plan_id="p", status="stepping")))
        assert at_obs.wait_for(lambda key, p: key == k.state(0)) and at_obs.wait_for(lambda key, p: key == k.tick)
        assert at_r0.wait_for(lambda key, p: key == k.tick)
        time.sleep(0.5)
        # nothing the observer put reached anyone: the only tick is the hub's, the only state robot 0's
        assert [decode(p, Tick).k for key, p in at_r0.items] == [1]
        assert [(key, decode(p, RobotState).status if key == k.state(0) else None) for key, p in at_hub.items
                if key != k.tick] == [(k.state(0), "stepping")]
        # It may say that it listens (a UAV waits for recorders), and nothing else through liveliness.
        tokens = Inbox()
        hub.watch_alive(f"{k.prefix}/alive/**", lambda key, alive: alive and tokens(key, b""))
        obs.announce(k.alive_uav)
        obs.announce(k.alive_robot(0))
        obs.announce(k.alive_observer("rec1"))
        assert tokens.wait_for(lambda key, p: key == k.alive_observer("rec1"))
        time.sleep(0.5)
        assert sorted({key for key, _ in tokens.items} - {k.alive_uav}) == [k.alive_observer("rec1")]


def test_only_the_world_answers_world_queries(fleet_dir):
    d, _ = fleet_dir
    k = Keys("sec")
    with _open_hub(d) as hub, _open(d, "robot-0") as r0, _open(d, "robot-1") as r1, _open(d, "world") as world:
        served = []
        for key in (k.camera, k.move, k.moves_by_identity):
            r0.serve(key, lambda q: (served.append(q.key), q.reply(b"forged")))
        world.serve(k.world_info, lambda q: q.reply(encode(WorldInfo(width=1, height=1, cell_size_m=1.0, home_lat=0.0, home_lon=0.0, home_alt_m=0.0))))
        assert _alive(r0, k.alive_uav)
        assert len(hub.request(k.world_info, encode(WorldInfoRequest()), WAIT_S)) == 1
        assert hub.request(k.camera, b"{}", 1.0) == []
        assert _alive(r1, k.alive_uav) and r1.request(k.move_as([1]), b"{}", 1.0) == []
        assert served == []


def test_the_world_moves_only_the_robots_the_key_names(mem_world):
    world, client = mem_world
    k = world.keys
    other = encode(MoveRequest(robot=1, tick=1, frm=(1, 0), to=(1, 1)))
    assert client.request(k.move_as([0]), other, 1.0) == []
    assert client.request(f"{k.move}/x", other, 1.0) == []
    res = decode(client.request(k.move_as([1]), other, 3.0)[0], MoveResult)
    assert res.accepted and res.cell == (1, 1)
    assert world.judge.positions[1] == (1, 1) and world.judge.positions[0] == (0, 0)


def _run(args: list[str], timeout: float = 240) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "uav_robots", "run", "--camera", "ideal", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})


@pytest.mark.slow
@pytest.mark.process
def test_a_secure_mission_completes_while_a_member_forges_everything(tmp_path):
    """The whole default mission over TLS with ACL, while robot 0's identity floods forged messages."""
    out = tmp_path / "out"
    proc = _run(["--secure", "--json", "--out", str(out), "--timeout", "200"])
    stop, seen_uav, sent = threading.Event(), threading.Event(), [0]

    def attack() -> None:
        deadline = time.monotonic() + 60
        while not (out / "secure" / "fleet.json").exists():
            if time.monotonic() > deadline or proc.poll() is not None:
                return
            time.sleep(0.05)
        fleet = read_fleet_dir(out / "secure")
        k = Keys(fleet.fleet)
        with open_session("attacker", config_file=str(out / "secure" / "robot-0.json5"), stop=stop, wait_s=30) as t:
            t.watch_alive(k.alive_uav, lambda _k, alive: alive and seen_uav.set())
            while not stop.is_set():
                for r in range(1, 8):
                    t.put(k.state(r), encode(RobotState(robot=r, tick=1, cell=(0, 0), plan_id="p", status="error")))
                    t.put(k.done(r), encode(Done(robot=r, tick=1, cell=(0, 0))))
                t.put(k.tick, encode(Tick(k=100_000, ticks=100_000, plan_id="p")))
                t.put(k.mission_end, encode(MissionEnd(completed=True)))
                t.request_start(k.move_as([1]), encode(MoveRequest(robot=1, tick=100_000, frm=(0, 0), to=(0, 1))), 0.05)
                sent[0] += 1
                stop.wait(0.02)

    th = threading.Thread(target=attack, daemon=True)
    th.start()
    try:
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        stop.set()
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        th.join(30)
    assert proc.returncode == 0, stderr[-2000:]
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["completed"] and summary["collisions"] == 0
    assert seen_uav.is_set() and sent[0] > 10   # the attacker was in the fleet, and sent all along
    assert "BEGIN" not in stdout and "PRIVATE KEY" not in json.dumps(summary)
    # The recorder listens with its own identity: the whole mission is in the recording.
    assert "no recording" not in stderr and (out / "mission.mcap").stat().st_size > 10_000


@pytest.mark.slow
@pytest.mark.process
def test_run_secure_uses_a_secure_init_directory_and_cleans_a_temporary_one(tmp_path):
    d = tmp_path / "made"
    init = subprocess.run([sys.executable, "-m", "uav_robots", "secure", "init", str(d), "--robots", "3",
                           "--fleet", "mine"], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert init.returncode == 0, init.stderr
    bad = subprocess.run([sys.executable, "-m", "uav_robots", "run", "--secure", str(d), "--robots", "4"],
                         capture_output=True, text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert bad.returncode == 2 and "made for 3 robots" in bad.stderr
    proc = _run(["--secure", str(d), "--robots", "3", "--json", "--map", "random:width=10,height=8,density=0.1"])
    stdout, stderr = proc.communicate(timeout=240)
    assert proc.returncode == 0, stderr[-2000:]
    assert json.loads(stdout.strip().splitlines()[-1])["completed"]
    tmp = Path(tempfile.gettempdir())
    before = set(tmp.glob("uav-robots-secure-*"))
    proc = _run(["--secure", "--robots", "2", "--json", "--map", "random:width=10,height=8,density=0.1"])
    stdout, stderr = proc.communicate(timeout=240)
    assert proc.returncode == 0, stderr[-2000:]
    assert set(tmp.glob("uav-robots-secure-*")) <= before


@pytest.mark.slow
def test_the_cost_bench_runs_a_lockstep_barrier_both_ways(tmp_path):
    """`uav-robots bench secure`'s transport part: ticks out and states back through the ACL'd router."""
    from uav_robots.bench.secure import barrier_rate

    assert barrier_rate(3, 20, None) > 0
    assert barrier_rate(3, 20, tmp_path / "s") > 0


@pytest.mark.parametrize("args, words", [
    (["secure", "init", "{d}", "--robots", "0"], "--robots must be in"),
    (["secure", "init", "{d}", "--robots", "3", "--address", "a/b"], "give a host name or an IP address"),
    (["secure", "init", "{d}", "--robots", "5000", "--robots-per-process", "1"], "at most 1024 identities"),
    (["run", "--secure", "{d}"], "no fleet.json"),
])
@pytest.mark.process
def test_bad_security_input_is_one_line_before_anything_is_written(tmp_path, args, words):
    d = tmp_path / "certs"
    r = subprocess.run([sys.executable, "-m", "uav_robots", *[a.format(d=d) for a in args]], capture_output=True,
                       text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 2 and words in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not d.exists()
