"""The fault catalogue: every fault `--fault SPEC` injects, one row each, named unit.kind as
MAVSDK's failure plugin names its failures (unit: what fails; kind: how).

A row holds the spec's grammar, its help line and the process that injects it; the process's
executor gives it its effect (a robot's agent: `robot_agents/agent.py`; the world's move judge:
`sim_world/faults.py`; the world's camera: `sim_world/camera_faults.py`; our vehicle: `sim_world/vehicle/`).
Adding a fault kind is one row here plus its executor there.

    robot.crash  crash:ROBOT@TICK        the robot dies when tick TICK arrives
    robot.stall  stall:ROBOT@TICK:TICKS  from tick TICK it neither moves nor reports, TICKS ticks long
    robot.liar   liar:ROBOT              it raises Done as soon as it has a plan, then never moves or reports
    world.slip   slip:P                  any move ends elsewhere with probability P
    world.skid   skid:ROBOT@TICK         from tick TICK every move of the robot ends elsewhere
    vehicle.battery  battery:PCT@SECONDS  after SECONDS simulated seconds in the air the pack holds PCT per cent
    camera.off    camera-off:SECONDS+DURATION    from SECONDS simulated seconds after the world starts, for
                                                 DURATION simulated seconds, the camera answers no request
    camera.stuck  camera-stuck:SECONDS+DURATION  in that window it answers with the last image it rendered
                                                 before it (the same pixels, pose, time and seq)
    link.mavlink  mavlink-loss:SECONDS+DURATION  from SECONDS simulated seconds after liftoff, for DURATION
                                                 simulated seconds, our vehicle's flight link carries nothing

Ticks count the UAV's clock (the `k` of `Tick`), so a stall ends when the rest of the fleet
has moved on that far, however long the UAV held it. Seconds are simulated: the clock the world
stamps its images with (the camera's windows) or our vehicle's (the battery, the link), which run
`--time-scale` times as fast as the wall clock.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from .errors import UavRobotsError

ROBOTS, WORLD, VEHICLE = "robots", "world", "vehicle"   # the processes that inject faults


@dataclass(frozen=True)
class FaultKind:
    unit: str
    kind: str
    form: str          # the spec's grammar, as a person writes it
    pattern: str       # the same, as a regular expression with named fields
    injector: str      # ROBOTS, WORLD or VEHICLE
    help: str

    @property
    def name(self) -> str:
        return f"{self.unit}.{self.kind}"


_INT, _PROB = r"\d+", r"[0-9.eE+-]+"
CATALOGUE: tuple[FaultKind, ...] = (
    FaultKind("robot", "crash", "crash:ROBOT@TICK", rf"crash:(?P<robot>{_INT})@(?P<tick>{_INT})", ROBOTS,
              "the robot dies at that tick"),
    FaultKind("robot", "stall", "stall:ROBOT@TICK:TICKS",
              rf"stall:(?P<robot>{_INT})@(?P<tick>{_INT}):(?P<ticks>{_INT})", ROBOTS,
              "it stops moving and reporting that long"),
    FaultKind("robot", "liar", "liar:ROBOT", rf"liar:(?P<robot>{_INT})", ROBOTS,
              "it raises Done at its start and stops"),
    FaultKind("world", "slip", "slip:P", rf"slip:(?P<p>{_PROB})", WORLD,
              "any move ends elsewhere with probability P"),
    FaultKind("world", "skid", "skid:ROBOT@TICK", rf"skid:(?P<robot>{_INT})@(?P<tick>{_INT})", WORLD,
              "from that tick every move of the robot does: it keeps deviating"),
    FaultKind("vehicle", "battery", "battery:PCT@SECONDS", rf"battery:(?P<pct>{_INT})@(?P<seconds>{_INT})", VEHICLE,
              "after SECONDS simulated seconds in the air our vehicle's pack holds only PCT per cent: its own "
              "failsafe acts"),
    FaultKind("camera", "off", "camera-off:SECONDS+DURATION",
              rf"camera-off:(?P<seconds>{_INT})\+(?P<duration>{_INT})", WORLD,
              "from SECONDS simulated seconds after the world starts, DURATION long, the camera answers no "
              "image request (a dead camera)"),
    FaultKind("camera", "stuck", "camera-stuck:SECONDS+DURATION",
              rf"camera-stuck:(?P<seconds>{_INT})\+(?P<duration>{_INT})", WORLD,
              "in that window the camera answers with the last image it rendered before it, pose, time and "
              "seq included (a frozen video pipeline)"),
    FaultKind("link", "mavlink", "mavlink-loss:SECONDS+DURATION",
              rf"mavlink-loss:(?P<seconds>{_INT})\+(?P<duration>{_INT})", VEHICLE,
              "from SECONDS simulated seconds after liftoff, DURATION long, our vehicle's flight link drops "
              "every message both ways: its datalink-loss failsafe (COM_DL_LOSS_T, NAV_DLL_ACT) acts"),
)
KINDS = {k.kind: k for k in CATALOGUE}


@dataclass(frozen=True)
class Fault:
    kind: str
    robot: int | None = None
    tick: int = 0
    ticks: int = 0
    p: float = 0.0
    pct: int = 0          # battery: the charge left, in per cent
    seconds: int = 0      # battery: simulated seconds in the air before the pack drops; a window's start
    duration: int = 0     # a window's length (camera-off, camera-stuck, mavlink-loss), simulated seconds

    @property
    def row(self) -> FaultKind:
        return KINDS[self.kind]

    @property
    def injector(self) -> str:
        return self.row.injector

    def __str__(self) -> str:
        return (self.row.form.replace("ROBOT", str(self.robot)).replace("TICKS", str(self.ticks))
                .replace("TICK", str(self.tick)).replace("PCT", str(self.pct)).replace("SECONDS", str(self.seconds))
                .replace("DURATION", str(self.duration))
                .replace("P", f"{self.p:g}"))

    def silent_at(self, k: int) -> bool:
        """True while the robot must neither move nor report at tick k."""
        if self.kind == "liar":
            return True
        if self.kind == "stall":
            return self.tick <= k < self.tick + self.ticks
        return False

    def active_at(self, t: float) -> bool:
        """True while a window fault (camera-off, camera-stuck, mavlink-loss) acts at `t` seconds on its clock."""
        return self.seconds <= t < self.seconds + self.duration


def usage(injector: str | None = None) -> str:
    """The grammars of the faults `injector` takes (every fault's if None), as one line."""
    forms = [k.form for k in CATALOGUE if injector in (None, k.injector)]
    return forms[0] if len(forms) == 1 else ", ".join(forms[:-1]) + " or " + forms[-1]


def help_line() -> str:
    """`--fault`'s help: each row's grammar and what it does, the robots', the world's, the vehicle's."""
    rows = {who: ", ".join(f"{k.form} ({k.help})" for k in CATALOGUE if k.injector == who)
            for who in (ROBOTS, WORLD, VEHICLE)}
    return f"inject a fault (repeatable): {rows[ROBOTS]}; the world's: {rows[WORLD]}; the vehicle's: {rows[VEHICLE]}"


def parse_fault(text: str, injector: str | None = None) -> Fault:
    """One fault spec; with `injector`, only a fault that process injects. One line for a bad one."""
    spec = text.strip()
    for row in CATALOGUE:
        if injector not in (None, row.injector):
            continue
        m = re.fullmatch(row.pattern, spec)
        if m is None:
            continue
        fields = m.groupdict()
        if "p" in fields:
            try:
                p = float(fields["p"])
            except ValueError:
                p = -1.0
            if not 0.0 <= p <= 1.0:
                raise UavRobotsError(f"--fault {text!r}: {row.form} takes P in [0, 1]")
            return Fault(row.kind, p=p)
        nums = {k: int(v) for k, v in fields.items()}
        if "tick" in nums and nums["tick"] < 1:
            raise UavRobotsError(f"--fault {text!r}: ticks start at 1")
        if "ticks" in nums and nums["ticks"] < 1:
            raise UavRobotsError(f"--fault {text!r}: a stall lasts at least one tick")
        if "pct" in nums and nums["pct"] > 100:
            raise UavRobotsError(f"--fault {text!r}: the pack holds at most 100 %")
        if "duration" in nums and nums["duration"] < 1:
            raise UavRobotsError(f"--fault {text!r}: DURATION is at least 1 simulated second")
        return Fault(row.kind, **nums)
    raise UavRobotsError(f"--fault {text!r}: give {usage(injector)}")


def split_faults(specs: list[str]) -> dict[str, list[Fault]]:
    """Specs by the process that injects them: {ROBOTS: [...], WORLD: [...], VEHICLE: [...]} (every key there)."""
    out: dict[str, list[Fault]] = {ROBOTS: [], WORLD: [], VEHICLE: []}
    for spec in specs:
        f = parse_fault(spec)
        out[f.injector].append(f)
    return out
