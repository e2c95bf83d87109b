"""Empties numba's caches of the planning kernels when any kernel source changed since they were filled.

numba checks a cached kernel against its own file only, yet a kernel holds the code of the
helpers it calls from other files: after an edit of `grid_kernels.py` alone, LaCAM's cached
search kept the old helpers (here: an object-mode clock whose module had lost `time`, a
NameError at run time; in general, silently old behaviour). A stamp beside the caches names
the sources they were compiled from.
"""
from __future__ import annotations

import os

from .cache import build_name, cache_dir, kernel_cache_dirs
from .lock import kernel_lock


def drop_stale_cache() -> None:
    home = cache_dir()
    stamp = home / "sources.stamp"
    name = build_name()
    try:
        if stamp.read_text() == name:
            return
    except OSError:
        pass
    with kernel_lock(what="stamp"):
        try:
            if stamp.read_text() == name:
                return      # another process has just done it
        except OSError:
            pass
        for d in kernel_cache_dirs():
            for old in list(d.glob("*.nbi")) + list(d.glob("*.nbc")):
                old.unlink(missing_ok=True)
        try:
            home.mkdir(parents=True, exist_ok=True)
            tmp = home / f".sources.stamp.{os.getpid()}"
            tmp.write_text(name)
            os.replace(tmp, stamp)
        except OSError:
            pass    # a cache directory numba cannot write to either: it then caches elsewhere
