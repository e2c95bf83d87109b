"""One compile at a time per cache: an exclusive lock (flock) on a file named after the cache.

The compiling process holds it, and whoever needs the kernels takes it first, so that it waits
and then loads them instead of compiling them a second time. Numba writes each cache file
atomically, but two processes that compile the same kernels waste the second core, and each
rewrites the whole index of a function: two writers can drop each other's entries, or give two
signatures the same data file.
"""
from __future__ import annotations

import errno
import fcntl
import hashlib
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from .cache import cache_dir


def lock_path(what: str = "kernels") -> Path:
    key = hashlib.blake2b(str(cache_dir()).encode(), digest_size=8).hexdigest()
    return Path(tempfile.gettempdir()) / f"uav-robots-{what}-{key}.lock"


def try_lock(fd: int, wait: bool) -> bool:
    """Takes the lock on the open file `fd`; False when `wait` is False and another process holds it."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
    except OSError as exc:
        if exc.errno in (errno.EAGAIN, errno.EACCES):
            return False
        raise
    return True


@contextmanager
def kernel_lock(wait: bool = True, what: str = "kernels") -> Iterator[bool]:
    """Holds the cache's compile lock (waiting for a compile in another process when `wait`);
    yields False when `wait` is False and another process holds it. `what="aot"`: the lock of
    the ahead-of-time build, which nobody waits for."""
    fd = os.open(lock_path(what), os.O_RDWR | os.O_CREAT, 0o666)
    try:
        yield try_lock(fd, wait)
    finally:
        os.close(fd)  # releases the lock


def busy() -> bool:
    """True while another process compiles (or loads) the kernels."""
    with kernel_lock(wait=False) as mine:
        return not mine
