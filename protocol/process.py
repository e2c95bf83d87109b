"""How every process of the system lives and dies.

One life cycle for the world and the robot pools (a stop flag with the reason it
was raised, the transport declarations to undeclare on the way out, signals that
end the serve loop), and one `main` wrapper for every command: SIGTERM unwinds
like Ctrl-C so that every `finally` closes its Zenoh session (a live session keeps
a process from exiting), and errors become one line and an exit code.
"""
from __future__ import annotations

import argparse
import ctypes
import gc
import signal
import sys
import threading
from typing import Any, Callable

from .errors import MissionError, UavRobotsError
from .run_spec import given_flags


def die_with_parent() -> None:
    """`preexec_fn` for subprocess.Popen: the kernel sends SIGTERM when the parent dies (Linux)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


class Lifecycle:
    """A serving process's stop flag, the first reason it was raised, and the declarations it holds."""

    def __init__(self, stop: threading.Event | None = None) -> None:
        self.stop = stop or threading.Event()
        self.exit_reason = ""
        self._handles: list[Any] = []

    def finish(self, reason: str) -> None:
        if not self.stop.is_set():
            self.exit_reason = reason
            self.stop.set()

    def keep(self, *handles: Any) -> None:
        self._handles.extend(handles)

    def release(self) -> None:
        """Undeclare in reverse order: liveliness tokens (declared last) go first."""
        self.stop.set()
        for h in reversed(self._handles):
            h.close()
        self._handles.clear()

    def stop_on_signals(self) -> None:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                signal.signal(sig, lambda *_: self.finish("signal"))

    def serve(self, poll_s: float = 0.5, check: Callable[[], None] | None = None) -> str:
        """Block until stopped, calling `check` every `poll_s`; returns why it stopped."""
        while not self.stop.wait(poll_s):
            if check is not None:
                check()
        return self.exit_reason


def one_command(prog: str, description: str, add_arguments: Callable[[argparse.ArgumentParser], None],
                func: Callable[[argparse.Namespace], int]) -> Callable[[list[str]], argparse.ArgumentParser]:
    """The parser builder of a process with one job (`python -m sim_world`, ...), for `command_main`."""
    def build(argv: list[str]) -> argparse.ArgumentParser:
        p = argparse.ArgumentParser(prog=prog, description=description)
        add_arguments(p)
        p.set_defaults(func=func)
        return p
    return build


def _unwind(signum: int, frame: object) -> None:
    raise SystemExit(143)


def command_main(build: Callable[[list[str]], argparse.ArgumentParser], argv: list[str] | None = None) -> int:
    """Parse `argv` with `build(argv)`'s parser and run its `func`; errors are one line and an exit code
    (1 a mission failed, 2 bad input, 130 interrupted)."""
    signal.signal(signal.SIGTERM, _unwind)
    own_process = argv is None      # the command itself, not a caller in a process that goes on
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build(argv).parse_args(argv)
    args.given_flags = given_flags(argv)   # what a run's --spec may not override (run_spec.apply_spec)
    try:
        return int(args.func(args) or 0)
    except MissionError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 1
    except UavRobotsError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr, flush=True)
        return 130
    finally:
        if own_process:
            # The process exits next, and the interpreter's collections at exit would walk every
            # object its libraries made (numba, OpenCV, Zenoh: some 140,000 in the UAV agent):
            # 0.3-0.4 s after a mission's work is over, 0.05 s frozen. Nothing is left for them
            # to do: sessions, children and files are closed by now, and weakref finalizers
            # (temporary directories) run at exit all the same.
            gc.freeze()
