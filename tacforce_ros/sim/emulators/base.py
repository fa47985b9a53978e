"""What every emulator shares: binding to loopback only, and deadline pacing on the monotonic
clock."""
from __future__ import annotations

import threading
import time

LOOPBACK = '127.0.0.1'


def require_loopback(host: str) -> str:
    """Emulators never listen beyond this machine."""
    if host != LOOPBACK:
        raise ValueError(f'emulators listen on {LOOPBACK} only, not {host!r}')
    return host


class Pacer:
    """Periodic deadlines at ``rate_hz``; when more than one period late it re-anchors instead
    of sending a burst (a real device does not catch up either)."""

    def __init__(self, rate_hz: float) -> None:
        if rate_hz <= 0:
            raise ValueError(f'rate must be positive, got {rate_hz}')
        self.period = 1.0 / rate_hz
        self._next = time.monotonic()

    def wait(self, stop: threading.Event) -> bool:
        """Sleep until the next deadline; False if ``stop`` was set meanwhile."""
        self._next += self.period
        delay = self._next - time.monotonic()
        if delay < -self.period:
            self._next = time.monotonic()
            delay = 0.0
        if delay > 0 and stop.wait(delay):
            return False
        return not stop.is_set()
