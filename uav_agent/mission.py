"""The UAV's mission: take off -> survey -> perceive -> plan -> dispatch -> step -> land -> report.

A thin process around pure parts: `flight` (MAVLink), `perception` (OpenCV),
`planning` (assignment, paths, validator), `fleet` (the robots over Zenoh).
The UAV never reads the world's ground truth; it asks the world's record only
after the mission, to score it.
"""
from __future__ import annotations

import json
import os
import secrets
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocol.config import DEFAULT_ENDPOINT, session_config
from protocol.errors import MissionError, ProtocolError
from protocol.keys import Keys
from protocol.messages import (CameraFrame, CameraRequest, MissionEnd, MissionStatus, Plan, Record, RecordRequest, Tick,
                               WorldInfo, WorldInfoRequest, decode, encode)
from protocol.transport import Transport, ZenohTransport

from .fleet import FleetLink
from .progress import Progress

QUERY_TIMEOUT_S = 10.0
ABORT_LAND_TIMEOUT_S = 60.0
RELOOK_ROUNDS = 2          # closer looks at markers whose id did not decode
RELOOK_MAX_CELLS = 20
RELOOK_MIN_ALT_M = 3.0


@dataclass
class MissionConfig:
    fleet: str
    robots: int | None = None               # expected fleet size; None = as many as the camera sees
    listen: list[str] = field(default_factory=list)   # hub mode: be the Zenoh router
    connect: list[str] = field(default_factory=list)  # or join an existing router
    zenoh_config: str | None = None
    mavlink_url: str = "udpin://0.0.0.0:14540"
    planner: str | None = None
    assign: str = "optimal"
    connectivity: int = 4
    time_limit_s: float = 60.0
    fallback: bool = True
    seed: int = 0
    out: Path | None = None
    startup_timeout_s: float = 30.0
    tick_timeout_s: float = 10.0
    min_px_per_cell: float = 20.0


class _Clock:
    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, phase: str) -> None:
        now = time.perf_counter()
        self.timings[phase] = round(self.timings.get(phase, 0.0) + now - self._t, 4)
        self._t = now


def _transport(cfg: MissionConfig) -> Transport:
    # The UAV is the hub unless told to join a router.
    hub = cfg.listen or ([] if cfg.connect or cfg.zenoh_config else [DEFAULT_ENDPOINT])
    return ZenohTransport(session_config(hub, cfg.connect, cfg.zenoh_config), "uav")


def _query(transport: Transport, key: str, request: Any, reply_type: type, what: str) -> Any:
    replies = transport.request(key, encode(request), QUERY_TIMEOUT_S)
    if not replies:
        raise MissionError(f"no answer from the world's {what} within {QUERY_TIMEOUT_S:g} s")
    try:
        return decode(replies[0], reply_type)
    except ProtocolError as exc:
        raise MissionError(f"the world's {what} answered garbage: {exc}") from None


class Mission:
    def __init__(self, cfg: MissionConfig, progress: Progress | None = None) -> None:
        self.cfg = cfg
        self.keys = Keys(cfg.fleet)
        self.progress = progress or Progress()
        self.clock = _Clock()
        self.seq = 0
        self.report: dict[str, Any] = {"format": "uav-robots-report/1", "completed": False}
        self.uav: dict[str, Any] = {"mavlink_url": cfg.mavlink_url, "armed": False,
                                    "max_altitude_m": 0.0, "hover": None, "landed": False}
        self.frames: list[CameraFrame] = []
        self._ended = False

    # ------------------------------------------------------------ helpers
    def _next(self) -> int:
        self.seq += 1
        return self.seq

    def _status(self, phase: str, **kw: Any) -> None:
        self.transport.put(self.keys.mission_status, encode(MissionStatus(phase=phase, seq=self._next(), **kw)))
        if phase != "executing":
            self.progress.phase(phase, kw.get("message", ""))

    def _track_altitude(self) -> None:
        north, east, down = self.flight.position_ned()
        self.uav["max_altitude_m"] = round(max(self.uav["max_altitude_m"], -down), 2)

    def _capture(self) -> CameraFrame:
        frame = _query(self.transport, self.keys.camera, CameraRequest(seq=self._next()), CameraFrame, "camera")
        self.frames.append(frame)
        return frame

    # ------------------------------------------------------------ phases
    def run(self) -> dict[str, Any]:
        from .flight import Flight

        self.transport = _transport(self.cfg)
        self.flight = None
        try:
            self._token = self.transport.announce(self.keys.alive_uav)
            self.fleet = FleetLink(self.transport, self.keys)
            self._status("connecting", message="waiting for the world on Zenoh")
            self.fleet.wait_until(lambda: self.fleet.world_alive, self.cfg.startup_timeout_s,
                                  lambda: f"no world on fleet {self.cfg.fleet} within {self.cfg.startup_timeout_s:g} s")
            info = _query(self.transport, self.keys.world_info, WorldInfoRequest(seq=self._next()), WorldInfo, "info")
            self.info = info
            self._warm = threading.Thread(target=self._warm_up_planner, name="planner-warm-up", daemon=True)
            self._warm.start()
            self.flight = Flight(self.cfg.mavlink_url)
            self.flight.connect(timeout_s=self.cfg.startup_timeout_s)
            self.clock.lap("connect")

            self._fly_and_survey()
            model = self._perceive()
            result = self._plan(model)
            self._dispatch(result)
            self._execute(result)
            self._end(True, "all robots at their goals")
            self._land()
            self._finish_report(result, model)
            return self.report
        except Exception:
            # A failed mission must not leave the drone hovering armed: land it, then report the failure.
            self._abort_landing()
            raise
        finally:
            if not self._ended:
                try:
                    self._end(False, "mission aborted")
                except Exception:  # noqa: BLE001 - the session may already be gone
                    pass
            if self.flight is not None:
                self.flight.close()
            if hasattr(self, "fleet"):
                self.fleet.close()
            self.transport.close()
            self.progress.close()

    def _warm_up_planner(self) -> None:
        from .planning.pipeline import warm_up
        from .planning.registry import DEFAULT_PLANNER

        try:
            warm_up(self.cfg.planner or DEFAULT_PLANNER, self.cfg.connectivity)
        except Exception:  # noqa: BLE001 - the real plan call reports any problem properly
            pass

    def _fly_and_survey(self) -> None:
        from .survey import survey_poses

        self._status("takeoff", message=f"arming and climbing over MAVLink ({self.cfg.mavlink_url})")
        self.flight.arm()
        self.uav["armed"] = True
        first = self._capture()  # on the ground: only to learn the camera's intrinsics
        self.frames.clear()
        poses = survey_poses(self.info.width, self.info.height, self.info.cell_size_m, first,
                             min_px_per_cell=self.cfg.min_px_per_cell)
        self.flight.takeoff(poses[0][2])
        self._track_altitude()
        self.clock.lap("takeoff")
        for i, (north, east, alt) in enumerate(poses):
            self._status("survey", message=f"image {i + 1}/{len(poses)} from {alt:.1f} m")
            self.flight.goto(north, east, alt)
            self._track_altitude()
            self._capture()
        # Hover over the floor's centre while the robots move: the leader keeps them in view.
        c = self.info.cell_size_m
        centre_n, centre_e = -self.info.height * c / 2, self.info.width * c / 2
        hover_alt = self._survey_alt = max(p[2] for p in poses)
        self._hover_ned = (centre_n, centre_e, hover_alt) if len(poses) > 1 else poses[-1]
        self.flight.goto(*self._hover_ned)
        n, e, d = self.flight.position_ned()
        self.uav["hover"] = [round(e / c, 2), round(-n / c, 2), round(-d, 2)]
        self._track_altitude()
        self.clock.lap("survey")

    def _perceive(self):
        from .perception import perceive

        # The robots on the network name the ids the camera may see; a marker read as any
        # other id is a misread, not a robot.
        expected = self.cfg.robots
        if expected is not None:
            self.fleet.wait_until(lambda: len(self.fleet.alive) >= expected, self.cfg.startup_timeout_s,
                                  lambda: f"only {len(self.fleet.alive)} of {expected} robots came alive "
                                          f"within {self.cfg.startup_timeout_s:g} s")
        with self.fleet.cv:
            known = set(self.fleet.alive) or None
        self._status("perceive", message=f"{len(self.frames)} image(s) through OpenCV")
        model = perceive(self.frames, self.info.width, self.info.height, self.info.cell_size_m, known_ids=known)
        for attempt in range(1, RELOOK_ROUNDS + 1):
            missing = sorted(set(known or ()) - set(model.robots))
            if not model.unidentified or not missing:
                break
            # A marker is there but its id did not decode: look again from lower down.
            cells = model.unidentified[:RELOOK_MAX_CELLS]
            self._status("perceive", message=f"{len(cells)} unreadable marker(s): a closer look (round {attempt})")
            scale = 2.0 ** attempt
            for x, y in cells:
                c = self.info.cell_size_m
                alt = max(RELOOK_MIN_ALT_M, self._survey_alt / scale)
                self.flight.goto(-(y + 0.5) * c, (x + 0.5) * c, alt)
                self._capture()
            model = perceive(self.frames, self.info.width, self.info.height, self.info.cell_size_m, known_ids=known)
            self.flight.goto(*self._hover_ned)
        if model.unseen:
            raise MissionError(f"perception: {model.unseen} cells were not seen by any image")
        if known is not None and set(model.robots) != known:
            raise MissionError(f"perception: robots {sorted(known - set(model.robots))[:10]} are alive on the network "
                               f"but not seen ({len(model.unidentified)} unreadable markers)")
        if expected is not None and len(model.robots) != expected:
            raise MissionError(f"perception found {len(model.robots)} robots, the mission expects {expected}")
        if len(model.goals) != len(model.robots):
            raise MissionError(f"perception found {len(model.robots)} robots but {len(model.goals)} goals")
        self.perception_warnings = model.warnings
        self.clock.lap("perceive")
        return model

    def _plan(self, model):
        from .planning.pipeline import plan_mission
        from .planning.registry import DEFAULT_PLANNER

        ids = sorted(model.robots)
        planner = self.cfg.planner or DEFAULT_PLANNER
        if self._warm.is_alive():
            self.progress.phase("plan", "compiling the planners (first run on this machine only, ~30 s; "
                                        "later runs load numba's cache)")
        self._warm.join()
        self._status("plan", message=f"{len(ids)} robots, planner {planner}, assignment {self.cfg.assign}")
        result = plan_mission(model.free, [model.robots[i] for i in ids], list(model.goals), planner=planner,
                              assign=self.cfg.assign, connectivity=self.cfg.connectivity,
                              time_limit=self.cfg.time_limit_s, fallback=self.cfg.fallback, seed=self.cfg.seed)
        for note in result.notes:
            self.progress.phase("plan", note)
        self.ids = ids
        self.model_free = model.free
        self.clock.lap("plan")
        return result

    def _dispatch(self, result) -> None:
        from .planning.types import Problem
        from .planning.validator import check

        # The validator is independent of the planners: nothing unchecked leaves the UAV.
        check(Problem(self.model_free, list(result.starts), list(result.goals), self.cfg.connectivity),
              result.paths)
        ids = self.ids
        self._status("dispatch", message=f"waiting for {len(ids)} robots to be alive, then sending plans")
        self.fleet.wait_until(lambda: set(ids) <= self.fleet.alive, self.cfg.startup_timeout_s,
                              lambda: f"robots {sorted(set(ids) - self.fleet.alive)[:10]} never came alive "
                                      f"within {self.cfg.startup_timeout_s:g} s")
        self.plan_id = secrets.token_hex(4)
        for rid, path, goal in zip(ids, result.paths, result.goals):
            self.transport.put(self.keys.plan(rid), encode(Plan(robot=rid, plan_id=self.plan_id, path=list(path),
                                                              goal=goal, seq=self._next())))
        pid = self.plan_id
        self.fleet.wait_until(
            lambda: all(self.fleet.acks.get(r) is not None and self.fleet.acks[r].plan_id == pid for r in ids),
            self.cfg.startup_timeout_s,
            lambda: f"robots {[r for r in ids if r not in self.fleet.acks][:10]} did not acknowledge their plan",
            abort=lambda: self.fleet.lost_among(ids))
        refused = [(r, self.fleet.acks[r].error) for r in ids if not self.fleet.acks[r].ok]
        if refused:
            raise MissionError(f"robot {refused[0][0]} refused its plan: {refused[0][1]}")
        self.clock.lap("dispatch")

    def _execute(self, result) -> None:
        ids = self.ids
        ticks = max(len(p) for p in result.paths) - 1
        self.ticks = ticks
        self._status("executing", tick=0, ticks=ticks, robots=len(ids), message="")
        self.progress.phase("execute", f"{ticks} ticks, {len(ids)} robots in lockstep")
        for k in range(1, ticks + 1):
            self.transport.put(self.keys.tick, encode(Tick(k=k, ticks=ticks, plan_id=self.plan_id, seq=self._next())))
            self.fleet.wait_until(
                lambda: all(self.fleet.last_tick.get(r, -1) >= k for r in ids), self.cfg.tick_timeout_s,
                lambda: f"robots {[r for r in ids if self.fleet.last_tick.get(r, -1) < k][:10]} "
                        f"did not report tick {k} within {self.cfg.tick_timeout_s:g} s",
                abort=lambda: self.fleet.lost_among(ids))
            done = len(self.fleet.done)
            self.progress.ticks(k, ticks, done, len(ids))
            if k % 10 == 0 or k == ticks:
                self.transport.put(self.keys.mission_status, encode(MissionStatus(
                    phase="executing", tick=k, ticks=ticks, done=done, robots=len(ids), seq=self._next())))
        self.fleet.wait_until(lambda: set(ids) <= set(self.fleet.done), self.cfg.tick_timeout_s,
                              lambda: f"robots {sorted(set(ids) - set(self.fleet.done))[:10]} never raised "
                                      "their completion flag")
        self.clock.lap("execute")

    def _end(self, completed: bool, reason: str) -> None:
        if self._ended:
            return
        self._ended = True
        self.transport.put(self.keys.mission_end, encode(MissionEnd(completed=completed, reason=reason,
                                                                    seq=self._next())))

    def _abort_landing(self) -> None:
        if self.flight is None or not self.uav["armed"] or self.uav["landed"]:
            return
        try:
            self._end(False, "mission aborted")
            self.progress.phase("abort", "landing the vehicle")
            self.flight.land(timeout_s=ABORT_LAND_TIMEOUT_S)
            self.uav["landed"] = True
        except Exception as exc:  # noqa: BLE001 - the link may be the thing that failed
            self.progress.phase("abort", f"could not land: {exc}")

    def _land(self) -> None:
        self._status("land", message="landing over MAVLink")
        self.flight.land()
        self.uav["landed"] = True
        self.clock.lap("land")

    def _finish_report(self, result, model) -> None:
        from .planning.plan_io import plan_to_dict

        record = _query(self.transport, self.keys.record, RecordRequest(seq=self._next()), Record, "record")
        plan = plan_to_dict(result, model.free, ids=self.ids)
        from protocol.mapfile import format_rows

        self.report.update({
            "completed": set(self.ids) <= set(self.fleet.done) and record.collisions == 0,
            "robots": len(self.ids),
            "done": sorted(self.fleet.done),
            "collisions": record.collisions,
            "refused": record.refused,
            "ticks": self.ticks,
            "plan": plan,
            "executed": record.executed,
            "perceived": {"rows": format_rows(model.free),
                          "robots": {str(i): list(c) for i, c in sorted(model.robots.items())},
                          "goals": [list(g) for g in model.goals],
                          "images": len(self.frames), "warnings": self.perception_warnings},
            "truth": record.truth,
            "uav": self.uav,
            "timings": self.clock.timings,
            "processes": {"uav": os.getpid()},
            "fleet": self.cfg.fleet,
        })
        self.clock.lap("report")
        self.report["timings"] = self.clock.timings
        if self.cfg.out is not None:
            write_outputs(self.cfg.out, self.report, self.frames, model.free, result, self.ids)


def write_outputs(out: Path, report: dict[str, Any], frames: list[CameraFrame], free, result,
                  ids: list[int]) -> None:
    """report.json, overhead.png (a captured image), paths.png and replay.gif into `out`."""
    from . import visualize

    out.mkdir(parents=True, exist_ok=True)
    if frames:
        (out / "overhead.png").write_bytes(frames[len(frames) // 2].png)
    visualize.write_png(out / "paths.png", visualize.draw_paths(free, result.paths, result.goals))
    executed = {int(k): [tuple(c) for c in v] for k, v in report["executed"].items()}
    goals = {rid: tuple(g) for rid, g in zip(ids, result.goals)}
    visualize.replay_gif(out / "replay.gif", free, executed, goals)
    (out / "report.json").write_text(json.dumps(report, indent=1))


def summary(report: dict[str, Any], out: Path | None) -> str:
    """The few lines a person reads at the end of a mission."""
    m = report["plan"]["metrics"]
    t = report["timings"]
    lines = [
        f"mission {'COMPLETED' if report['completed'] else 'FAILED'}: {len(report['done'])}/{report['robots']} robots "
        f"at their goals in {report['ticks']} ticks, collisions {report['collisions']}",
        f"  plan: {report['plan'].get('planner', '?')}, sum of costs {m['sum_of_costs']} "
        f"(lower bound {m.get('lower_bound', '?')}), makespan {m['makespan']}",
        f"  uav: armed {report['uav']['armed']}, max altitude {report['uav']['max_altitude_m']} m, "
        f"landed {report['uav']['landed']}",
        "  time: " + ", ".join(f"{k} {v:.2f}s" for k, v in t.items()),
    ]
    if out:
        lines.append(f"  outputs: {out}/report.json, overhead.png, paths.png, replay.gif")
    return "\n".join(lines)
