"""A run's whole configuration in one record: `RunSpec`, written by `uav-robots run` to OUT/run.json
and copied into report.json, read by every process it starts (`--spec FILE`).

A process given `--spec` takes from it what it needs; a flag given on its own command line still
wins (standalone use, a test that changes one thing). `uav-robots run --spec OUT/run.json` repeats
that run: the same map, placement, faults and planner, hence the same plan.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .errors import UavRobotsError
from .faults import parse_fault

FORMAT = "uav-robots-run/1"
RUN_JSON = "run.json"


@dataclass(frozen=True)
class CameraSpec:
    source: str = "zenoh"        # how the UAV takes its images: zenoh, mavlink or video
    model: str = ""              # the world's camera, `[PRESET,]K=V,...` (docs/camera-and-perception.md)


@dataclass(frozen=True)
class SceneSpec:
    """What the world lays on the floor for the camera (scenarios/scene.py)."""
    landmark_spacing: int = 12               # cells between surveyed landmarks (0: none)
    goal_pads: bool = True                   # goals as green pads a robot on them leaves visible
    people: int = 0                          # uncooperative movers (sim_world/movers.py) the world walks
    forklifts: int = 0
    pallets: int = 0
    routes: str | None = None                # a file of scripted movers (`sim_world.movers.read_routes`)

    def text(self) -> str:
        """As `--scene` takes it (every key given: no preset needed)."""
        movers = "".join(f",{k}={v}" for k, v in (("people", self.people), ("forklifts", self.forklifts),
                                                  ("pallets", self.pallets)) if v)
        return (f"landmark_spacing={self.landmark_spacing},goal_pads={int(self.goal_pads)}{movers}"
                + (f",routes={self.routes}" if self.routes else ""))

    @property
    def movers(self) -> bool:
        return bool(self.people or self.forklifts or self.pallets or self.routes)


@dataclass(frozen=True)
class VehicleSpec:
    preset: str = "outdoor"                  # our vehicle: outdoor (GPS, a home) or indoor (its local frame)
    time_scale: float = 10.0                 # simulated seconds per wall second
    wobble_deg: float = 0.3                  # our vehicle's roll and pitch wobble in a hover (amplitude)
    autopilot: str | None = None             # another autopilot's link instead of our vehicle (the UAV's)
    autopilot_pose: str | None = None        # ... and the link the world reads its pose on
    autopilot_origin: str | None = None
    gcs: str | None = None                   # a ground station's link on our vehicle
    mavlink_key: str | None = None
    mavlink_bind: str = "127.0.0.1"


@dataclass(frozen=True)
class PlanningSpec:
    planner: str | None = None               # None: the default planner
    assign: str | None = None                # None: the default assignment
    connectivity: int = 4
    time_limit_s: float = 60.0
    fallback: bool = True


@dataclass(frozen=True)
class LimitsSpec:
    tick_timeout_s: float = 10.0
    tick_rate_hz: float = 0.0
    monitor_every: int | None = None
    look_every: int | None = None            # the UAV's looks for movers (None: once its survey saw one)
    timeout_s: float = 900.0


@dataclass(frozen=True)
class HostingSpec:
    robots_per_process: int | None = None
    secure: str | None = None                # None: plain; "": a fresh CA; else the fleet directory


@dataclass(frozen=True)
class RunSpec:
    map: str = "warehouse-small"
    robots: int = 8
    seed: int = 0
    scen: str | None = None                  # a MovingAI .scen: starts and goals (else placed by the seed)
    camera: CameraSpec = field(default_factory=CameraSpec)
    scene: SceneSpec = field(default_factory=SceneSpec)
    vehicle: VehicleSpec = field(default_factory=VehicleSpec)
    faults: tuple[str, ...] = ()             # fault specs (protocol/faults.py), each injected by its process
    planning: PlanningSpec = field(default_factory=PlanningSpec)
    limits: LimitsSpec = field(default_factory=LimitsSpec)
    hosting: HostingSpec = field(default_factory=HostingSpec)

    def faults_for(self, injector: str) -> list[str]:
        """The fault specs `injector` (protocol.faults.ROBOTS, WORLD or VEHICLE) injects."""
        return [f for f in self.faults if parse_fault(f).injector == injector]

    def as_dict(self) -> dict[str, Any]:
        return {"format": FORMAT, **dataclasses.asdict(self), "faults": list(self.faults)}

    def to_json(self) -> str:
        return json.dumps(self.as_dict(), indent=1)


_SECTIONS = {"camera": CameraSpec, "scene": SceneSpec, "vehicle": VehicleSpec, "planning": PlanningSpec, "limits": LimitsSpec,
             "hosting": HostingSpec}


def _typed(where: str, value: Any, kind: Any) -> Any:
    """`value` if it is of the field's type (`kind`, as the annotation spells it); one line if not."""
    text = str(kind)
    ok = (value is None and "None" in text) or \
        (isinstance(value, bool) and "bool" in text) or \
        (isinstance(value, int) and not isinstance(value, bool) and ("int" in text or "float" in text)) or \
        (isinstance(value, float) and "float" in text) or (isinstance(value, str) and "str" in text)
    if not ok:
        raise UavRobotsError(f"run spec: {where} is {value!r}, not {text}")
    return float(value) if "float" in text and isinstance(value, int) and "int" not in text else value


# The choices the commands' flags offer (argparse checks them on a command line, not in a spec).
CHOICES = {"camera.source": ("zenoh", "mavlink", "video"), "vehicle.preset": ("outdoor", "indoor"),
           "planning.connectivity": (4, 8)}


def _section(name: str, cls: type, data: Any) -> Any:
    if not isinstance(data, dict):
        raise UavRobotsError(f"run spec: {name} must be an object")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise UavRobotsError(f"run spec: {name} has no field {unknown[0]!r} (it has {', '.join(fields)})")
    for k, v in data.items():
        allowed = CHOICES.get(f"{name}.{k}")
        if allowed is not None and v not in allowed:
            raise UavRobotsError(f"run spec: {name}.{k} is {v!r}, not one of {', '.join(map(str, allowed))}")
    return cls(**{k: _typed(f"{name}.{k}", v, fields[k].type) for k, v in data.items()})


def spec_from_dict(data: Any) -> RunSpec:
    """A RunSpec from run.json's object; one line naming the first bad field."""
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise UavRobotsError(f"run spec: not a {FORMAT} object (its \"format\" is {data.get('format')!r})"
                             if isinstance(data, dict) else "run spec: not a JSON object")
    body = {k: v for k, v in data.items() if k != "format"}
    top = {f.name: f for f in dataclasses.fields(RunSpec)}
    unknown = sorted(set(body) - set(top))
    if unknown:
        raise UavRobotsError(f"run spec: no field {unknown[0]!r} (it has {', '.join(top)})")
    kw: dict[str, Any] = {}
    for name, value in body.items():
        if name in _SECTIONS:
            kw[name] = _section(name, _SECTIONS[name], value)
        elif name == "faults":
            if not (isinstance(value, list) and all(isinstance(f, str) for f in value)):
                raise UavRobotsError("run spec: faults must be a list of fault specs")
            for f in value:
                parse_fault(f)
            kw[name] = tuple(value)
        else:
            kw[name] = _typed(name, value, top[name].type)
    return RunSpec(**kw)


def read_spec(path: str | Path) -> RunSpec:
    try:
        data = json.loads(Path(path).read_text())
    except OSError as exc:
        raise UavRobotsError(f"--spec {path}: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise UavRobotsError(f"--spec {path}: not JSON: {exc}") from None
    try:
        return spec_from_dict(data)
    except UavRobotsError as exc:
        raise UavRobotsError(f"--spec {path}: {exc}") from None


# ----------------------------------------------------------------- a process's flags from the spec
# flag -> its value in the spec. Each process names the flags it takes from a spec; the launcher
# gives it `--spec` and the flags that are its alone (session, ports, robot ids).
Fields = dict[str, Callable[[RunSpec], Any]]


def add_spec_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--spec", default=None, metavar="FILE",
                   help=f"a run's {RUN_JSON} (written by `uav-robots run`): its values are this command's "
                        "defaults; flags given here still override them")


def given_flags(argv: list[str]) -> set[str]:
    """The long options on a command line (`--flag` or `--flag=value`)."""
    return {tok.split("=", 1)[0] for tok in argv if tok.startswith("--")}


def apply_spec(args: argparse.Namespace, fields: Fields) -> RunSpec | None:
    """With `--spec FILE`: every flag of `fields` not given on the command line takes the spec's value.
    Returns the spec (None without --spec)."""
    if not getattr(args, "spec", None):
        return None
    spec = read_spec(args.spec)
    given = getattr(args, "given_flags", set())
    for flag, value in fields.items():
        if flag not in given:
            setattr(args, flag.lstrip("-").replace("-", "_"), value(spec))
    return spec
