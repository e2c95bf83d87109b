"""How every process of the system lives and dies: children that die with their parent."""
from __future__ import annotations

import ctypes
import signal


def die_with_parent() -> None:
    """`preexec_fn` for subprocess.Popen: the kernel sends SIGTERM when the parent dies (Linux)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass
