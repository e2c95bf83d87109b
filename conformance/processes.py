"""Implementations under test as processes: command lines from templates, started in a group, stopped for sure."""
from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
from pathlib import Path

from protocol.errors import MissionError

REPO = Path(__file__).resolve().parents[1]
DEFAULT_ROBOT_CMD = f"{shlex.quote(sys.executable)} -m robot_agents --id {{id}} --fleet {{fleet}} --connect {{endpoint}}"
DEFAULT_POOL_CMD = f"{shlex.quote(sys.executable)} -m robot_agents --ids {{ids}} --fleet {{fleet}} --connect {{endpoint}}"


def robot_command(template: str, robot: int | list[int], fleet: str, endpoint: str) -> list[str]:
    """The command line from a template: {id} for one robot; {ids} (comma-separated) for a pool."""
    ids = robot if isinstance(robot, list) else [robot]
    try:
        text = template.format(id=ids[0], ids=",".join(map(str, ids)), fleet=fleet, endpoint=endpoint)
    except (KeyError, IndexError, ValueError) as exc:
        raise MissionError(f"robot command {template!r}: bad placeholder {exc}; use {{id}} (or {{ids}} for a pool) "
                           "{fleet} {endpoint}") from None
    return shlex.split(text)


def start_robot(template: str, robot: int | list[int], fleet: str, endpoint: str,
                log: Path | None = None) -> subprocess.Popen:
    argv = robot_command(template, robot, fleet, endpoint)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH", "")]))
    out = open(log, "wb") if log is not None else subprocess.DEVNULL
    try:
        # A new session: the robot and any children it starts can be killed as one group.
        return subprocess.Popen(argv, cwd=REPO, env=env, stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    finally:
        if log is not None:
            out.close()


def stop_process(proc: subprocess.Popen, grace: float = 3.0) -> int | None:
    """SIGTERM the process group, then SIGKILL it; returns the exit code (None if it had to be killed)."""
    if proc.poll() is None:
        signal_group(proc, signal.SIGTERM)
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            signal_group(proc, signal.SIGKILL)
            proc.wait(5)
            return None
    return proc.returncode


def signal_group(proc: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass
