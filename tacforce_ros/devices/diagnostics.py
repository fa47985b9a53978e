"""Link-health counters shared by every device driver (and the emulators' request side)."""
from __future__ import annotations

import dataclasses
import math
import threading
import time
from dataclasses import dataclass


@dataclass
class LinkDiagnostics:
    """Counters of one device link; a driver mutates them, readers take :meth:`snapshot` copies.

    ``dropped`` counts every input discarded for any reason; ``malformed`` is the subset that
    could not be decoded (bad JSON, wrong length, wrong DLC, wrong taxel count). ``gaps`` counts
    samples missing according to the device's sequence numbers (or incomplete CAN cycles), and
    ``reordered`` inputs that arrived older than one already delivered (they are dropped).
    ``late_polls`` counts polls the host ran late enough that the driver could not have seen
    the device (its thread was not scheduled); that time is not counted as device silence.
    """

    received: int = 0
    delivered: int = 0
    dropped: int = 0
    malformed: int = 0
    gaps: int = 0
    reordered: int = 0
    reconnects: int = 0
    late_polls: int = 0
    status_warnings: int = 0
    status_errors: int = 0
    last_seen: float = math.nan      # time.monotonic() of the last input, NaN before the first
    last_error: str = ''
    _lock: threading.Lock = dataclasses.field(default_factory=threading.Lock, repr=False,
                                              compare=False)

    def note_received(self, now: float | None = None) -> None:
        with self._lock:
            self.received += 1
            self.last_seen = time.monotonic() if now is None else now

    def note_malformed(self, reason: str) -> None:
        """Count one undecodable input as malformed and dropped, remembering why."""
        with self._lock:
            self.malformed += 1
            self.dropped += 1
            self.last_error = reason

    def add(self, **increments: int) -> None:
        """Increment named counters atomically, e.g. ``add(gaps=3, dropped=1)``."""
        with self._lock:
            for name, value in increments.items():
                setattr(self, name, getattr(self, name) + value)

    def age(self, now: float | None = None) -> float:
        """Seconds since the last input (monotonic clock); ``inf`` if nothing arrived yet."""
        if math.isnan(self.last_seen):
            return math.inf
        return (time.monotonic() if now is None else now) - self.last_seen

    def snapshot(self) -> LinkDiagnostics:
        """A consistent copy, safe to read while the driver keeps counting."""
        with self._lock:
            return dataclasses.replace(self)


# Levels of a link's health, numbered as diagnostic_msgs/DiagnosticStatus numbers them.
OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR', STALE: 'STALE'}
# Counters whose increase over a report period makes the link WARN (data was lost or bad).
TROUBLE_COUNTERS = ('malformed', 'gaps', 'reordered', 'reconnects')


def link_health(now: LinkDiagnostics, before: LinkDiagnostics | None,
                failure: str = '') -> tuple[int, str]:
    """Level and message of a link over one report period, from two snapshots of its
    counters (`before` None: the first report). `failure`: what the driver knows to be wrong
    beyond the counters (a lost link, a hand made safe), which makes the link ERROR.

    STALE: nothing has arrived yet. ERROR: the failure, or nothing arrived during the period
    while something had before. WARN: data arrived but TROUBLE_COUNTERS rose. OK otherwise.
    """
    if failure:
        return ERROR, failure
    if math.isnan(now.last_seen):
        return STALE, 'no data from the device yet'
    if before is not None and now.received == before.received:
        return ERROR, f'no data for {now.age():.1f} s'
    rose = {name: getattr(now, name) - (getattr(before, name) if before else 0)
            for name in TROUBLE_COUNTERS}
    rose = {name: value for name, value in rose.items() if value > 0}
    if rose:
        return WARN, ('data lost or refused since the last report: '
                      + ', '.join(f'{value} {name}' for name, value in rose.items())
                      + (f' (last error: {now.last_error})' if now.last_error else ''))
    return OK, 'streaming'


def sequence_delta(new: int, last: int, bits: int = 32) -> int:
    """Signed difference ``new - last`` of wrapping unsigned counters (2**bits - 1 -> 0 is +1)."""
    half = 1 << (bits - 1)
    return ((new - last + half) % (1 << bits)) - half


@dataclass(frozen=True)
class ArrivalStamp:
    """When the host received an input: ``monotonic`` for latency/age, ``wall`` (Unix s) for
    message headers."""

    monotonic: float
    wall: float

    @classmethod
    def now(cls) -> ArrivalStamp:
        return cls(time.monotonic(), time.time())
