"""The one wait every fake of the suites shares: until a predicate holds, or a timeout."""
from __future__ import annotations

import threading
import time
from typing import Callable


class Waiter:
    """A condition variable with `until(predicate, timeout)`, shared by the fakes."""

    def __init__(self) -> None:
        self.cv = threading.Condition()

    def changed(self) -> None:
        with self.cv:
            self.cv.notify_all()

    def until(self, pred: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        with self.cv:
            while not pred():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.cv.wait(min(left, 0.2))
            return True
