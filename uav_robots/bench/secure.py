"""`uav-robots bench secure`: what mutual TLS and access control cost, in execution ticks per second.

Boundary: whole `uav-robots run --json` commands (every process started and stopped), the
figure being the UAV's own execution phase: ticks / timings.execute from report.json, with
--monitor-every 0 so that no camera image falls inside it. Plain and --secure runs alternate
(the order flips each repetition) so that a change in machine load hits both alike.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from protocol.errors import UavRobotsError


def one_run(robots: int, map_spec: str, seed: int, secure: bool, timeout_s: float) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "uav_robots", "run", "--json", "--robots", str(robots), "--map", map_spec,
           "--seed", str(seed), "--monitor-every", "0", *(["--secure"] if secure else []),
           # the camera the earlier runs in bench-results/secure used (the default became the realistic one)
           "--camera", "ideal"]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise UavRobotsError(f"a {'secure' if secure else 'plain'} run took over {timeout_s:g} s") from None
    lines = r.stdout.strip().splitlines()
    summary = json.loads(lines[-1]) if lines else {}
    if r.returncode != 0 or not summary.get("completed"):
        raise UavRobotsError(f"a {'secure' if secure else 'plain'} run failed (exit {r.returncode}): "
                             f"{summary.get('reason') or r.stderr.strip()[-300:]}")
    t = summary["timings"]
    return {"mode": "secure" if secure else "plain", "robots": robots, "seed": seed, "ticks": summary["ticks"],
            "execute_s": t["execute"], "ticks_per_s": round(summary["ticks"] / t["execute"], 1),
            "wall_s": t["wall_total"], "collisions": summary["collisions"]}


def barrier_rate(robots: int, ticks: int, secure_dir: Path | None) -> float:
    """Lockstep ticks/s of the transport alone, in this process: a router with the UAV's config puts a
    tick, `robots` client sessions (each with its own identity when secure) answer with a state."""
    import threading
    import time

    from protocol.config import client_config, hub_config
    from protocol.keys import Keys
    from protocol.transport import ZenohTransport

    from ..common.ports import free_port

    port = free_port()
    if secure_dir is None:
        hub_cfg, fleet = hub_config([f"tcp/127.0.0.1:{port}"]), "bench"
        cfgs = [client_config([f"tcp/127.0.0.1:{port}"], 5000)] * robots
        over: dict[str, Any] = {}
    else:
        from ..secure.fleet import make_fleet_dir, new_fleet

        made = new_fleet("bench", robots, [[r] for r in range(robots)], ["127.0.0.1"], port, secure_dir)
        make_fleet_dir(secure_dir, made)
        hub_cfg, fleet = (secure_dir / "uav.json5").read_text(), "bench"
        cfgs = [(secure_dir / f"robot-{r}.json5").read_text() for r in range(robots)]
        over = {"connect/timeout_ms": 5000}
    k = Keys(fleet)
    got, lock, all_in = [0], threading.Lock(), threading.Event()

    def on_state(_key: str, _p: bytes) -> None:
        with lock:
            got[0] += 1
            if got[0] == robots:
                all_in.set()

    with ZenohTransport(hub_cfg, "bench hub") as hub:
        hub.subscribe(k.all_states, on_state)
        clients = [ZenohTransport(c, f"bench robot {r}", over) for r, c in enumerate(cfgs)]
        try:
            for r, c in enumerate(clients):
                c.subscribe(k.tick, lambda _k, p, r=r, c=c: c.put(k.state(r), p))
            time.sleep(1.0)   # every subscription known to the router
            t0 = time.perf_counter()
            for tick in range(ticks):
                with lock:
                    got[0] = 0
                all_in.clear()
                hub.put(k.tick, str(tick).encode())
                if not all_in.wait(10):
                    raise UavRobotsError(f"bench secure: barrier tick {tick} incomplete after 10 s")
            return ticks / (time.perf_counter() - t0)
        finally:
            for c in clients:
                c.close()


def table(runs: list[dict[str, Any]]) -> str:
    rows = ["| mode | runs | ticks | execution ticks/s (median) | all runs, ticks/s | whole run wall s (median) |",
            "|---|---|---|---|---|---|"]
    med: dict[str, float] = {}
    for mode in ("plain", "secure"):
        rs = [r for r in runs if r["mode"] == mode and "failed" not in r]
        if not rs:
            raise UavRobotsError(f"bench secure: every {mode} run failed")
        med[mode] = statistics.median(r["ticks_per_s"] for r in rs)
        each = ", ".join(f"{r['ticks_per_s']:.0f}" for r in rs)
        rows.append(f"| {mode} | {len(rs)} | {rs[0]['ticks']} | {med[mode]:.0f} | {each} | "
                    f"{statistics.median(r['wall_s'] for r in rs):.2f} |")
    failed = [f"{r['mode']}: {r['failed']}" for r in runs if "failed" in r]
    rows.append(f"\nsecure / plain execution ticks/s: {med['secure'] / med['plain']:.2f}")
    if failed:
        rows.append(f"\nfailed runs (left out): {'; '.join(failed)}")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    if (not 1 <= args.robots <= 1000 or not 1 <= args.repeat <= 100 or not 1 <= args.barrier_ticks <= 10**6
            or not args.run_timeout > 0):
        raise UavRobotsError("bench secure: --robots in [1, 1000], --repeat in [1, 100], --barrier-ticks in "
                             "[1, 1000000], --run-timeout > 0")
    runs: list[dict[str, Any]] = []
    load_before = os.getloadavg()[0]
    import tempfile

    barrier: dict[str, list[float]] = {"plain": [], "secure": []}
    for i in range(args.repeat):
        for secure in ((False, True) if i % 2 == 0 else (True, False)):
            with tempfile.TemporaryDirectory(prefix="uav-robots-bench-") as tmp:
                rate = barrier_rate(args.robots, args.barrier_ticks, Path(tmp) / "s" if secure else None)
            barrier["secure" if secure else "plain"].append(rate)
            print(f"  barrier {'secure' if secure else 'plain':6s} {rate:.0f} ticks/s", flush=True)
    med = {m: statistics.median(v) for m, v in barrier.items()}
    barrier_md = ("| mode | runs | lockstep ticks/s (median) | all runs |\n|---|---|---|---|\n" + "".join(
        f"| {m} | {len(v)} | {med[m]:.0f} | {', '.join(f'{x:.0f}' for x in v)} |\n" for m, v in barrier.items())
        + f"\nsecure / plain lockstep ticks/s: {med['secure'] / med['plain']:.2f}\n")
    for i in range(args.repeat):
        for secure in ((False, True) if i % 2 == 0 else (True, False)):
            try:
                r = one_run(args.robots, args.map, args.seed, secure, args.run_timeout)
            except UavRobotsError as exc:   # a loaded machine can fail a run: counted, not hidden
                print(f"  {'secure' if secure else 'plain':6s} failed: {exc}", flush=True)
                runs.append({"mode": "secure" if secure else "plain", "failed": str(exc)})
                continue
            print(f"  {r['mode']:6s} {r['ticks']} ticks in {r['execute_s']:.3f} s: {r['ticks_per_s']:.0f} ticks/s",
                  flush=True)
            runs.append(r)
    text = (f"# Security cost: execution ticks per second, plain vs --secure\n\n"
            f"`uav-robots bench secure --robots {args.robots} --map {args.map} --seed {args.seed} "
            f"--repeat {args.repeat}` ({os.cpu_count()} cores). Boundary: whole `uav-robots run` commands, "
            f"alternating; the figure is ticks / the UAV's execution phase (report.json), "
            f"--monitor-every 0. Load average (1 min) {load_before:.1f} before, {os.getloadavg()[0]:.1f} after: "
            f"other work on the machine shares its cores.\n\n"
            f"**Transport alone** (boundary: one process; a router opened with the UAV's config puts a "
            f"tick, {args.robots} client sessions, each with its own certificate when secure, answer with "
            f"a state; {args.barrier_ticks} ticks per run):\n\n{barrier_md}\n"
            f"**Whole missions** (boundary: whole `uav-robots run` commands):\n\n{table(runs)}\n")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "secure.md").write_text(text)
    (out / "secure-runs.json").write_text(json.dumps(runs, indent=1) + "\n")
    print(text, flush=True)
    return 0


def add_parser(sub: Any) -> argparse.ArgumentParser:
    ps = sub.add_parser("secure", help="execution ticks/s with and without --secure, alternating",
                        description="Runs whole missions alternately plain and with --secure and compares "
                                    "execution ticks per second.")
    ps.add_argument("--robots", type=int, default=50, help="robots per run (default 50)")
    ps.add_argument("--map", default="warehouse:blocks_x=6,blocks_y=4", help="map of every run")
    ps.add_argument("--seed", type=int, default=0)
    ps.add_argument("--repeat", type=int, default=3, help="runs of each mode (default 3)")
    ps.add_argument("--barrier-ticks", type=int, default=300, help="ticks per in-process barrier run (default 300)")
    ps.add_argument("--run-timeout", type=float, default=600.0, help="seconds one run may take")
    ps.add_argument("--out", default="bench-out", help="directory for secure.md and secure-runs.json")
    return ps
