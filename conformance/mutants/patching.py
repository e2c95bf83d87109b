"""How a mutant is made: patches, applied before the implementation's main runs, each replacing one attribute."""
from __future__ import annotations

import dataclasses
from typing import Callable

Patch = Callable[[], None]


def replace(msg, **changes):
    return dataclasses.replace(msg, **changes)


def setattr_(owner: object, name: str, value: object) -> Patch:
    """The patch that sets `owner.name` to `value`."""
    return lambda: setattr(owner, name, value)


# A robot pool's `_put(self, rid, key, msg)` around the real one, `put` (taken before any patch).
def put_if(put: Callable, keep: Callable[[object], bool]):
    def filtered(self, rid, key, msg):
        if keep(msg):
            put(self, rid, key, msg)
    return filtered


def put_changed(put: Callable, change: Callable[[object], object]):
    def changed(self, rid, key, msg):
        put(self, rid, key, change(msg))
    return changed
