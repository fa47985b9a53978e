"""Approximate-time pairing of several message streams, pure Python (no rclpy).

message_filters' ApproximateTimeSynchronizer is not installable from PyPI;
this keeps its user-facing semantics: one bounded queue per input (`queue_size`), and a set is
emitted as soon as one message per input lies within `slop` seconds of each other (max stamp -
min stamp <= slop), preferring, for each other input, the message closest in time to the one
that just arrived. Beyond message_filters' Python version it guarantees a clean output stream:

* no message is used twice, and once a set is emitted every queued message older than the
  message used from its input is dropped (it could only produce an out-of-order set);
* each input's stamps in the output strictly increase, so any input's stamp is a monotone clock
  for the output; a message arriving older than the last one used from its input is dropped;
* every dropped message is counted per input (`dropped`), by reason (`drop_reasons`).

Stamps are integer nanoseconds (a float of Unix seconds resolves only ~0.2 us).
"""
from __future__ import annotations

import itertools
from collections import Counter
from typing import Any, Generic, TypeVar

T = TypeVar('T')

DROP_OVERFLOW = 'overflow'      # queue full: the oldest message was pushed out
DROP_SUPERSEDED = 'superseded'  # older than a message already emitted from the same input
DROP_LATE = 'late'              # arrived older than the last emitted message of its input


class ApproximateTimeSynchroniser(Generic[T]):
    """Pairs `n_inputs` streams; `add()` returns the emitted set (one message per input)."""

    def __init__(self, n_inputs: int, queue_size: int, slop: float) -> None:
        if n_inputs < 2:
            raise ValueError(f'n_inputs: {n_inputs} must be at least 2')
        if queue_size < 1:
            raise ValueError(f'queue_size: {queue_size} must be at least 1')
        if not slop >= 0.0:
            raise ValueError(f'slop: {slop} must be >= 0 seconds')
        self.n_inputs = n_inputs
        self.queue_size = int(queue_size)
        self.slop_ns = int(round(slop * 1e9))
        self._queues: list[list[tuple[int, T]]] = [[] for _ in range(n_inputs)]
        self._last_used: list[int | None] = [None] * n_inputs
        self.emitted = 0
        self.dropped = [0] * n_inputs
        self.drop_reasons: list[Counter[str]] = [Counter() for _ in range(n_inputs)]

    def queue_lengths(self) -> list[int]:
        return [len(q) for q in self._queues]

    def _drop(self, index: int, reason: str, count: int = 1) -> None:
        if count:
            self.dropped[index] += count
            self.drop_reasons[index][reason] += count

    def add(self, index: int, stamp_ns: int, msg: T) -> tuple[T, ...] | None:
        """Queue one message of input `index`; return a complete set if one is now ready."""
        if not 0 <= index < self.n_inputs:
            raise IndexError(f'input {index} out of range 0..{self.n_inputs - 1}')
        stamp_ns = int(stamp_ns)
        last = self._last_used[index]
        if last is not None and stamp_ns <= last:
            self._drop(index, DROP_LATE)
            return None
        queue = self._queues[index]
        entry = (stamp_ns, msg)
        queue.append(entry)
        queue.sort(key=lambda e: e[0])
        if len(queue) > self.queue_size:
            pushed_out = queue.pop(0)
            self._drop(index, DROP_OVERFLOW)
            if pushed_out is entry:     # arrived older than a full queue: nothing to pair
                return None
        return self._match(index, stamp_ns, msg)

    def _match(self, index: int, stamp_ns: int, msg: T) -> tuple[T, ...] | None:
        # Candidates per other input within slop of the new message, nearest first.
        choices: list[list[tuple[int, Any]]] = []
        for other, queue in enumerate(self._queues):
            if other == index:
                choices.append([(stamp_ns, msg)])
                continue
            near = [e for e in queue if abs(e[0] - stamp_ns) <= self.slop_ns]
            if not near:
                return None
            choices.append(sorted(near, key=lambda e: abs(e[0] - stamp_ns)))
        for combo in itertools.product(*choices):
            stamps = [entry[0] for entry in combo]
            if max(stamps) - min(stamps) <= self.slop_ns:
                self._consume(stamps)
                self.emitted += 1
                return tuple(entry[1] for entry in combo)
        return None

    def _consume(self, stamps: list[int]) -> None:
        """Remove the used messages and every older one (counted as superseded)."""
        for index, used in enumerate(stamps):
            queue = self._queues[index]
            older = sum(1 for e in queue if e[0] < used)
            self._drop(index, DROP_SUPERSEDED, older)
            self._queues[index] = [e for e in queue if e[0] > used]
            self._last_used[index] = used
