"""A minimal robot speaking the uav-robots protocol over Zenoh (docs/protocol.md), usable in place of ours.

    python3 examples/minimal_robot.py                                   # a real mission flown with 3 of these robots
    python3 examples/minimal_robot.py --id 3 --fleet F --connect tcp/127.0.0.1:7447    # one robot on a fleet

`robot()` below is the whole robot: it acknowledges its plan, asks the world to move it one cell
per tick, reports its state and raises its flag (`Done`) on its goal. It uses only `protocol`
(keys, messages, the Zenoh session), as a robot on a real machine would; our own robot is
robot_agents/. The conformance suite checks any robot started from a command line:

    uav-robots conformance robot --cmd "python3 examples/minimal_robot.py --id {id} --fleet {fleet} --connect {endpoint}"

This one keeps every rule the suite checks of a single robot but one: told the mission is over
while the world has not yet answered its move, it waits out its 5 s move timeout before it exits.
(`-k "liveliness or follow_the_plan or exits_on"` runs a part of the suite: see examples/README.md.)

Without arguments it flies a small mission the way docs/deploying.md runs the parts alone: our UAV
(`python -m uav_agent`, the Zenoh router), our world (`python -m sim_world`, with its own simulated
vehicle) and three of these robots in place of `uav-robots robot`.
"""
from __future__ import annotations

import argparse
import itertools
import queue
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # the checkout, even without `pip install -e .`

from protocol.codec import decode, encode
from protocol.errors import UavRobotsError
from protocol.keys import Keys, new_fleet_name
from protocol.messages import (PROTOCOL_VERSION, Done, MissionEnd, MoveRequest, MoveResult, Plan, PlanAck, RobotState,
                               Tick)
from protocol.process import die_with_parent
from protocol.transport import open_session

REPO = Path(__file__).resolve().parents[1]
MOVE_TIMEOUT_S = 5.0      # docs/protocol.md, QoS: a robot waits this long for the world's answer to a move


def why_not(plan: Plan, rid: int, cell, last_tick: int) -> str:
    """'' if this robot can execute `plan`, else a one-line reason (sent back in the PlanAck)."""
    p, diagonal = plan.path, (plan.connectivity or 4) == 8
    steps = [(abs(a[0] - b[0]), abs(a[1] - b[1])) for a, b in zip(p, p[1:])]
    if plan.robot != rid or not plan.plan_id or not p or p[-1] != plan.goal:
        return f"not a plan robot {rid} can follow (another robot's, no id, empty, or not ending on its goal)"
    if any(max(dx, dy) > 1 if diagonal else dx + dy > 1 for dx, dy in steps):
        return "a step of the path is not a move to a neighbouring cell"
    if plan.start_tick and plan.start_tick < last_tick:
        return f"the plan starts at tick {plan.start_tick}, before tick {last_tick}, already executed"
    if not plan.start_tick and cell is not None and p[0] != cell:
        return f"the plan starts at {p[0]}, the robot stands on {cell}"
    return ""


def robot(rid: int, fleet: str, endpoint: str, max_s: float = 3600.0) -> int:
    keys, inbox, stop, seq = Keys(fleet), queue.Queue(), threading.Event(), itertools.count(1)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    # The plan held, its base tick (path[i] is the cell at tick base + i), the cell the world last said
    # the robot stands on (None before its first answer), the status, the last tick executed, the
    # highest tick heard of, and the plan whose flag was raised.
    plan, base, cell, status, last, seen, flagged = None, 0, None, "idle", 0, 0, ""
    uav_seen = threading.Event()

    def on_uav(_key: str, alive: bool) -> None:
        if alive:
            uav_seen.set()
        elif uav_seen.is_set():                 # the UAV's liveliness token went away: the mission is over
            stop.set()

    with open_session(f"robot {rid}", connect=[endpoint], stop=stop) as zenoh:   # a client of the UAV's router
        # Listen first; the liveliness token last: the UAV sends plans only once it sees the token.
        zenoh.subscribe(keys.plan(rid), lambda _k, data: inbox.put((Plan, data)))
        zenoh.subscribe(keys.tick, lambda _k, data: inbox.put((Tick, data)))
        zenoh.subscribe(keys.mission_end, lambda _k, data: inbox.put((MissionEnd, data)))
        zenoh.watch_alive(keys.alive_uav, on_uav)
        zenoh.announce(keys.alive_robot(rid))
        print(f"robot {rid} ready on fleet {fleet}", flush=True)
        deadline = time.monotonic() + max_s
        while not stop.is_set() and time.monotonic() < deadline:
            try:
                kind, data = inbox.get(timeout=0.2)
                msg = decode(data, kind)          # garbage, a wrong version or a broken limit raise: dropped
            except (queue.Empty, UavRobotsError):
                continue
            if kind is MissionEnd:
                break
            if kind is Plan:                      # acknowledge every plan; hold it if it can be executed
                if plan is not None and msg.plan_id == plan.plan_id:      # resent: the same plan, or a mistake
                    same = (msg.path, msg.goal) == (plan.path, plan.goal)
                    error = "" if same else f"plan {msg.plan_id} was received before with another path"
                else:
                    error = why_not(msg, rid, cell, last)
                    if not error:
                        plan, base, status = msg, msg.start_tick or seen, "ready"
                        if msg.start_tick:        # a repair: the UAV's camera says where the robot stands
                            cell = msg.path[0]
                zenoh.put(keys.ack(rid), encode(PlanAck(robot=rid, plan_id=msg.plan_id, ok=not error, error=error,
                                                        protocol=PROTOCOL_VERSION, seq=next(seq))))
                continue
            seen = max(seen, msg.k)
            if plan is None or msg.k <= last:     # no plan yet, or a resent or late tick: nothing to do
                continue
            ours = msg.plan_id == plan.plan_id    # a tick naming another plan: stay where it stands
            frm = cell if cell is not None else plan.path[0]
            to = plan.path[min(max(msg.k - base, 0), len(plan.path) - 1)] if ours else frm
            ask = MoveRequest(robot=rid, tick=msg.k, frm=frm, to=to, seq=next(seq))
            replies = zenoh.request(keys.move_as([rid]), encode(ask), MOVE_TIMEOUT_S)   # the world judges the move
            answer = next((r for r in map(_move_result, replies) if r and (r.robot, r.tick) == (rid, msg.k)), None)
            last = msg.k
            if answer is None:                    # an error state names the last known cell, for this tick only
                state = RobotState(robot=rid, tick=msg.k, cell=frm, status="error", plan_id=plan.plan_id,
                                   error=f"no answer from the world to the move of tick {msg.k}", seq=next(seq))
            else:
                cell = answer.cell                # where the world says it stands, moved or not
                if ours:                          # else the status stays what it was
                    over = msg.k - base >= len(plan.path) - 1
                    status = "done" if over and cell == plan.goal else "stepping"
                state = RobotState(robot=rid, tick=msg.k, cell=cell, status=status, plan_id=plan.plan_id,
                                   error=answer.reason, seq=next(seq))
            zenoh.put(keys.state(rid), encode(state))
            if state.status == "done" and flagged != plan.plan_id:      # the flag, once per plan
                flagged = plan.plan_id
                zenoh.put(keys.done(rid), encode(Done(robot=rid, tick=msg.k, cell=cell, seq=next(seq))))
    print(f"robot {rid}: stopped", flush=True)
    return 0


def _move_result(raw: bytes) -> MoveResult | None:
    try:
        return decode(raw, MoveResult)
    except UavRobotsError:
        return None


# ------------------------------------------------------------------------ the demonstration
def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def mission(robots: int = 3, timeout_s: float = 120.0) -> int:
    """Our UAV and world, and `robots` of these robots: the explicit form of docs/deploying.md."""
    fleet, endpoint = new_fleet_name(), f"tcp/127.0.0.1:{_free_port(socket.SOCK_STREAM)}"
    mavlink = _free_port(socket.SOCK_DGRAM)                 # the world's vehicle sends MAVLink there
    n = ["--fleet", fleet, "--robots", str(robots)]
    children: list[subprocess.Popen] = []

    def start(*argv: str, **kw) -> subprocess.Popen:    # a child that dies with this process, whatever happens
        children.append(subprocess.Popen([sys.executable, *argv], cwd=REPO, stdin=subprocess.DEVNULL,
                                         preexec_fn=die_with_parent, **kw))
        return children[-1]

    with tempfile.TemporaryDirectory(prefix="minimal-robot-") as out:
        try:
            uav = start("-m", "uav_agent", *n, "--listen", endpoint, "--quiet", "--out", out,
                        "--mavlink", f"udpin://127.0.0.1:{mavlink}",
                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            start("-m", "sim_world", *n, "--connect", endpoint, "--mavlink", f"udpout:127.0.0.1:{mavlink}",
                  "--time-scale", "10", "--camera", "ideal", stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            for i in range(robots):
                start(__file__, "--id", str(i), "--fleet", fleet, "--connect", endpoint, stdout=subprocess.DEVNULL)
            try:
                report, _ = uav.communicate(timeout=timeout_s)
                for child in children[2:]:       # the robots stop by themselves on the UAV's MissionEnd
                    child.wait(timeout=10)
            except subprocess.TimeoutExpired as exc:
                raise UavRobotsError(f"{' '.join(map(str, exc.cmd[1:4]))} ... did not end in time") from None
        finally:
            for child in reversed(children):
                if child.poll() is None:
                    child.terminate()
                    try:
                        child.wait(timeout=5)
                    except subprocess.TimeoutExpired:
                        child.kill()
                        child.wait()
    summary = [line for line in report.splitlines() if line.startswith(("mission ", "  plan:"))]
    print("\n".join(summary) or report[-2000:])
    if uav.returncode != 0 or not summary[:1] or not summary[0].startswith("mission COMPLETED"):
        raise UavRobotsError(f"the mission with minimal robots failed (UAV exit code {uav.returncode})")
    print(f"{robots} minimal robots (examples/minimal_robot.py) completed a mission of our UAV and world")
    return 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--id", type=int, help="this robot's id (without it: the demonstration mission)")
    ap.add_argument("--fleet", default="default", help="the fleet: keys live under uavr/<fleet>")
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447", help="the Zenoh router (the UAV) to join")
    a = ap.parse_args()
    try:
        sys.exit(mission() if a.id is None else robot(a.id, a.fleet, a.connect))
    except UavRobotsError as exc:
        sys.exit(f"minimal_robot: {exc}")
