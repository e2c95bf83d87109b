"""ArduCopter SITL as a process for tests, when `UAV_ROBOTS_ARDUPILOT_SITL` names its binary.

The repository carries none of ArduPilot's code or build steps: build ArduCopter SITL from its public
sources as ArduPilot's own documentation says, then
`UAV_ROBOTS_ARDUPILOT_SITL=<checkout>/build/sitl/bin/arducopter python3 -m pytest tests/uav_agent/test_real_autopilot.py`.
Its default parameters are the checkout's own (`Tools/autotest/default_params/copter.parm`, found from
the binary's place in the checkout, or named by `UAV_ROBOTS_ARDUPILOT_DEFAULTS`), as `sim_vehicle.py`
starts it. Without the variable every test that needs it is skipped, saying why.

Its links are MAVLink over UDP to loopback ports the test listens on (`udpclient`), one per party as on
a real drone: SERIAL0 the UAV agent's, SERIAL1 the world's pose reader's, SERIAL2 a ground station's.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
from pathlib import Path

import pytest

ENV, DEFAULTS_ENV = "UAV_ROBOTS_ARDUPILOT_SITL", "UAV_ROBOTS_ARDUPILOT_DEFAULTS"
HOME = (47.397742, 8.545594, 488.0)   # any place: the floor is pinned where the autopilot's first home is
# ArduPilot SITL's RC input port is 5501 + 10 * instance, its serial ports' TCP ones 5760 + 10 * instance:
# an instance whose ports are free, so that a SITL someone left running is no trouble.
INSTANCES = range(20, 60)


def binary() -> Path:
    """The ArduCopter SITL binary the environment names, or skip the test saying how to give one."""
    named = os.environ.get(ENV, "")
    if not named:
        pytest.skip(f"{ENV} names no ArduCopter SITL binary (build one from ArduPilot's sources, "
                    "as its documentation says; see docs/autopilots.md)")
    path = Path(named).expanduser()
    if not (path.is_file() and os.access(path, os.X_OK)):
        pytest.fail(f"{ENV}={named}: not an executable file")
    return path


def defaults(sitl: Path) -> Path:
    """The copter defaults of the checkout the binary was built in (build/sitl/bin/arducopter)."""
    named = os.environ.get(DEFAULTS_ENV, "")
    path = Path(named).expanduser() if named else \
        sitl.resolve().parents[3] / "Tools" / "autotest" / "default_params" / "copter.parm"
    if not path.is_file():
        pytest.fail(f"no ArduCopter default parameters at {path}: name them with {DEFAULTS_ENV}")
    return path


def _free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _instance() -> int:
    for i in INSTANCES:
        if _free(5501 + 10 * i, socket.SOCK_DGRAM) and all(_free(5760 + 10 * i + k, socket.SOCK_STREAM)
                                                           for k in range(4)):
            return i
    pytest.fail("no free ArduPilot SITL instance ports")


class ArduCopter:
    """One ArduCopter SITL process in `workdir` (its eeprom.bin and logs), sending MAVLink to
    127.0.0.1:`uav_port` (SERIAL0), `pose_port` (SERIAL1) and `gcs_port` (SERIAL2)."""

    def __init__(self, workdir: Path, uav_port: int, pose_port: int, gcs_port: int, speedup: float = 1.0,
                 params: dict[str, float] | None = None):
        self.binary = binary()
        self.workdir = workdir
        self.ports = uav_port, pose_port, gcs_port
        self.speedup = speedup
        self.params = dict(params or {})
        self.log = workdir / "arducopter.log"
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> "ArduCopter":
        self.workdir.mkdir(parents=True, exist_ok=True)
        files = [defaults(self.binary)]
        if self.params:   # the test's own, after the checkout's (later files win)
            ours = self.workdir / "test.parm"
            ours.write_text("".join(f"{k} {v:g}\n" for k, v in self.params.items()))
            files.append(ours)
        uav, pose, gcs = self.ports
        cmd = [str(self.binary), "--model", "quad", "--speedup", f"{self.speedup:g}", "-I", str(_instance()),
               "--home", ",".join(f"{v:g}" for v in HOME) + ",0", "--defaults", ",".join(map(str, files)),
               "--serial0", f"udpclient:127.0.0.1:{uav}", "--serial1", f"udpclient:127.0.0.1:{pose}",
               "--serial2", f"udpclient:127.0.0.1:{gcs}", "--wipe"]
        with open(self.log, "w") as log:
            self.proc = subprocess.Popen(cmd, cwd=self.workdir, stdout=log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, start_new_session=True)
        return self

    def __exit__(self, *exc) -> None:
        proc, self.proc = self.proc, None
        if proc is None or proc.poll() is not None:
            return
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def said(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""
