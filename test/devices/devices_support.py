"""Helpers for the device tests: bounded waiting on a condition."""
from __future__ import annotations

import time
from collections.abc import Callable

# The bound on waiting for an event that takes milliseconds on an idle machine: the hosts that
# run CI take every thread's CPU away for up to ~2 s at a time, about once a second.
EVENT_TIMEOUT = 15.0


def wait_until(condition: Callable[[], bool], timeout: float = 5.0, period: float = 0.005) -> bool:
    """Poll ``condition`` until true or ``timeout`` s pass; returns its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(period)
    return condition()
