"""Robot processes forked from a server that has already imported them.

A robot process spends ~0.15 CPU-s starting Python and importing the protocol and
Zenoh before it does anything; fifty of them take both cores of a small machine
for seconds, while the UAV surveys the floor. multiprocessing's forkserver
imports that once; each robot is then a fork of it: a process of its own, with
its own log and its own Zenoh session, opened after the fork (the server never
opens one, so no Zenoh runtime thread is ever forked). Linux and macOS have
forkserver; elsewhere `available()` is False and callers start `python -m
robot_agents` as before.
"""
from __future__ import annotations

import multiprocessing
import os
import select
import signal
import subprocess
import sys

# "__main__": a forkserver child otherwise runs the launcher's main script again (the
# `uav-robots` console script, its imports and all) before it runs the robot; the server
# imports it once instead (a `-m` main module is never re-run).
PRELOAD = ["__main__", "robot_agents.agent", "protocol.transport", "zenoh", "setproctitle"]


def available() -> bool:
    return "forkserver" in multiprocessing.get_all_start_methods()


def _context():
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(PRELOAD)
    return ctx


def _main(argv: list[str], log: str | None) -> None:
    """A robot process's life, as `python -m robot_agents ARGV` with its output to `log`."""
    from setproctitle import setproctitle

    from protocol.process import die_with_parent

    from .agent import robot_main

    die_with_parent()   # the server dies with the launcher, and the robot with the server
    # What `ps` and `pgrep -f` show: the robot's own command, not the server's.
    setproctitle(" ".join([os.path.basename(sys.executable), "-m", "robot_agents", *argv]))
    if log is not None:
        fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)
        sys.stdout = open(1, "w", buffering=1, closefd=False)
        sys.stderr = open(2, "w", buffering=1, closefd=False)
    # The server ignores SIGINT (multiprocessing protects it from ^C); a robot ends on it.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.exit(robot_main(argv))


class Forked:
    """A forked robot process behind subprocess.Popen's interface (what the launcher uses of it)."""

    def __init__(self, argv: list[str], log: str | None) -> None:
        self._p = _context().Process(target=_main, args=(list(argv), log), daemon=False)
        self._p.start()
        self.pid = self._p.pid
        self.args = ["robot_agents", *argv]
        # The launcher looks at every child 20 times a second. multiprocessing's exitcode builds
        # a selector around the sentinel each time: for 50 robots 6 % of a core, all mission long.
        # One registered poll object asks the kernel alone until the sentinel says the robot ended.
        self._ended = select.poll()
        self._ended.register(self._p.sentinel, select.POLLIN)
        self._code: int | None = None

    @property
    def returncode(self) -> int | None:
        return self.poll()

    def poll(self) -> int | None:
        if self._code is None and self._ended.poll(0):
            self._code = self._p.exitcode
        return self._code

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:    # not reaped yet, so the pid is still this robot's
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def wait(self, timeout: float | None = None) -> int:
        self._p.join(timeout)
        if self._p.exitcode is None:
            raise subprocess.TimeoutExpired(self.args, timeout)
        return self._p.exitcode
