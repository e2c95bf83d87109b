"""Watch a running fleet over Zenoh: its phases, every tick, each robot's states and flags, the mission's end.

    python3 examples/observe_fleet.py                                       # starts a small `uav-robots run` and watches it
    python3 examples/observe_fleet.py --connect tcp/127.0.0.1:PORT --fleet FLEET   # a fleet already running

An observer is one more Zenoh client of the UAV's router: it subscribes to keys under the fleet's
prefix `uavr/<fleet>` (protocol/keys.py, docs/protocol.md *Keys*) and decodes what it hears with
protocol/codec.py (the messages: protocol/messages.py). It needs no hook in the processes it watches. `uav-robots run` prints its
fleet and Zenoh endpoint on its first line (`... fleet f1a2b3c4d, zenoh tcp/127.0.0.1:PORT, ...`):
that is all an observer needs to join it.
"""
from __future__ import annotations

import argparse
import queue
import re
import secrets
import select
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # the checkout, even without `pip install -e .`

from protocol.codec import decode
from protocol.errors import UavRobotsError
from protocol.keys import Keys
from protocol.messages import Done, MissionEnd, MissionStatus, RobotState, StateBatch, Tick
from protocol.process import die_with_parent
from protocol.transport import open_session

REPO = Path(__file__).resolve().parents[1]


def observe(endpoint: str, fleet: str, timeout_s: float) -> int:
    """Print what the fleet says until its MissionEnd (or `timeout_s`); 0 if the mission completed."""
    keys, inbox = Keys(fleet), queue.Queue()
    listen = {keys.mission_status: MissionStatus, keys.tick: Tick, keys.all_states: RobotState,
              keys.all_state_batches: StateBatch, keys.all_done: Done, keys.mission_end: MissionEnd}
    phase, ticks, states, cells, done, end = "", 0, 0, {}, {}, None
    with open_session("observer", connect=[endpoint], wait_s=min(20.0, timeout_s)) as zenoh:
        for key, kind in listen.items():        # callbacks run on Zenoh's threads: only hand the bytes over
            zenoh.subscribe(key, lambda _key, data, kind=kind: inbox.put((kind, data)))
        zenoh.announce(keys.alive_observer(f"example-{secrets.token_hex(3)}"))   # optional: "I listen"
        print(f"observer: joined fleet {fleet} at {endpoint}", flush=True)
        deadline = time.monotonic() + timeout_s
        while end is None and time.monotonic() < deadline:
            try:
                kind, data = inbox.get(timeout=0.5)
                msg = decode(data, kind)
            except (queue.Empty, UavRobotsError):    # nothing yet, or a message that does not decode
                continue
            if kind is MissionStatus:                # said at each phase change and every 10 ticks
                if msg.phase != phase:
                    phase = msg.phase
                    print(f"phase {phase}" + (f": {msg.message}" if msg.message else ""), flush=True)
            elif kind is Tick:
                ticks += 1
                print(f"tick {msg.k}/{msg.ticks} of plan {msg.plan_id}", flush=True)
            elif kind in (RobotState, StateBatch):   # a pool may report its robots' states in one batch
                for st in msg.robot_states() if kind is StateBatch else [msg]:
                    states += 1
                    cells.setdefault(st.robot, []).append(st.cell)
            elif kind is Done:
                done[msg.robot] = msg
                print(f"robot {msg.robot} raised its flag: on its goal {msg.cell} at tick {msg.tick}", flush=True)
            elif kind is MissionEnd:
                end = msg
    for robot in sorted(cells):
        trail = cells[robot]
        print(f"robot {robot}: {len(trail)} states, first on {trail[0]}, last on {trail[-1]}"
              + (" (done)" if robot in done else ""))
    print(f"observer: saw {ticks} ticks, {states} robot states, {len(done)} done flags")
    if end is None:
        raise UavRobotsError(f"no MissionEnd within {timeout_s:g} s")
    print(f"mission end: {'completed' if end.completed else 'not completed: ' + end.reason}")
    return 0 if end.completed and ticks else 1


def with_a_mission(timeout_s: float) -> int:
    """Start a small `uav-robots run` and observe it from beside, as any outside process could."""
    run = subprocess.Popen([sys.executable, "-m", "uav_robots", "run", "--robots", "3", "--camera", "ideal",
                            "--tick-rate", "10", "--timeout", str(timeout_s)],
                           cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                           text=True, preexec_fn=die_with_parent)     # it dies with this process, whatever happens
    try:
        ready, _, _ = select.select([run.stdout], [], [], 30.0)
        first = run.stdout.readline() if ready else ""
        found = re.search(r"fleet (\S+), zenoh (\S+),", first)
        if not found:
            raise UavRobotsError(f"`uav-robots run` did not say its fleet and endpoint: {first.strip()!r}")
        code = observe(found[2], found[1], timeout_s)
        rest, _ = run.communicate(timeout=30)       # its own summary, for comparison
        print("uav-robots run said: " + next((l for l in rest.splitlines() if l.startswith("mission ")), "?"))
        return code if run.returncode == 0 else 1
    finally:
        if run.poll() is None:
            run.terminate()                         # the launcher stops its children in order
            try:
                run.wait(timeout=20)
            except subprocess.TimeoutExpired:
                run.kill()
                run.wait()


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", help="the fleet's Zenoh endpoint (without it: start a mission to watch)")
    ap.add_argument("--fleet", help="the fleet's name (with --connect)")
    ap.add_argument("--timeout", type=float, default=90.0, help="give up after this many seconds (default 90)")
    a = ap.parse_args()
    try:
        if bool(a.connect) != bool(a.fleet):
            raise UavRobotsError("give both --connect and --fleet, or neither")
        sys.exit(observe(a.connect, a.fleet, a.timeout) if a.connect else with_a_mission(a.timeout))
    except (UavRobotsError, subprocess.TimeoutExpired) as exc:
        sys.exit(f"observe_fleet: {exc}")
