"""The UAV under test as a process: its command line from the suite's template, started in a group of its own."""
from __future__ import annotations

import os
import shlex
import socket
import subprocess
from pathlib import Path

from protocol.errors import MissionError

from ..processes import REPO
from .options import PLACEHOLDERS


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def uav_command(template: str, *, fleet: str, endpoint: str, mavlink_port: int, robots: int,
                tick_timeout: float) -> list[str]:
    try:
        text = template.format(fleet=fleet, endpoint=endpoint, mavlink=f"udpin://127.0.0.1:{mavlink_port}",
                               mavlink_port=mavlink_port, robots=robots, tick_timeout=f"{tick_timeout:g}")
    except (KeyError, IndexError, ValueError) as exc:
        raise MissionError(f"--uav-cmd {template!r}: bad placeholder {exc}; use {PLACEHOLDERS}") from None
    return shlex.split(text)


def start_process(argv: list[str], stdout: Path, stderr: Path) -> subprocess.Popen:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH", "")]))
    with open(stdout, "wb") as out, open(stderr, "wb") as err:
        # A new session: the UAV and any children it starts are stopped as one process group.
        return subprocess.Popen(argv, cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                start_new_session=True)
