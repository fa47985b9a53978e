"""The driving pattern every device driver shares: ``poll()`` from the caller's own thread or
executor, or ``start()`` a background thread that polls; callbacks, latest sample, staleness, and
events (faults and recoveries worth a log line, with a logging level) for whoever runs the
driver: a node turns them into its own log lines."""
from __future__ import annotations

import abc
import logging
import threading
from collections.abc import Callable
from typing import Generic, TypeVar

from tacforce_ros.devices.diagnostics import LinkDiagnostics

SampleT = TypeVar('SampleT')
EventCallback = Callable[[int, str], None]      # (logging level, message)
log = logging.getLogger(__name__)


class LinkLost(ConnectionError):
    """The transport to the device is gone (peer closed, reset, unplugged)."""


class PollingDriver(abc.ABC, Generic[SampleT]):
    """Base of the drivers: subclasses implement ``_receive`` (bounded by its timeout) and
    ``_shutdown``; a fatal error in the background thread calls ``_on_fatal`` and stops it."""

    def __init__(self, stale_after: float, poll_timeout: float = 0.05) -> None:
        self.diagnostics = LinkDiagnostics()
        self.stale_after = float(stale_after)
        self.poll_timeout = float(poll_timeout)
        self._callbacks: list[Callable[[SampleT], None]] = []
        self._event_callbacks: list[EventCallback] = []
        self._latest: SampleT | None = None
        self._count = 0
        self._new_sample = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self.fatal_error: BaseException | None = None

    @abc.abstractmethod
    def _receive(self, timeout: float) -> list[SampleT]:
        """Wait at most ``timeout`` s for input; return the samples it completed."""

    @abc.abstractmethod
    def _shutdown(self) -> None:
        """Leave the device in a safe state and release the transport (called once)."""

    def _on_fatal(self, error: BaseException) -> None:
        """Hook for drivers that must make the device safe on an unexpected error."""

    def _before_stop(self) -> None:
        """Hook for drivers that must make the device safe on close(): called while the
        background thread still reads the link. Stopped first, a streaming device fills the
        unread link, and a server that cuts off a client that does not read loses what is sent
        after."""

    def add_callback(self, callback: Callable[[SampleT], None]) -> None:
        """Call ``callback(sample)`` for every delivered sample (from the polling thread)."""
        self._callbacks.append(callback)

    def add_event_callback(self, callback: EventCallback) -> None:
        """Call ``callback(level, message)`` for every event (faults, recoveries); without one,
        events go to this module's logger."""
        self._event_callbacks.append(callback)

    def _event(self, level: int, message: str) -> None:
        if level >= logging.WARNING:
            self.diagnostics.last_error = message
        for callback in self._event_callbacks or [lambda lv, text: log.log(lv, '%s', text)]:
            callback(level, message)

    def poll(self, timeout: float = 0.0) -> list[SampleT]:
        """Process input for at most ``timeout`` s; deliver and return the completed samples."""
        samples = self._receive(timeout)
        if samples:
            with self._new_sample:
                self._latest = samples[-1]
                self._count += len(samples)
                self._new_sample.notify_all()
            self.diagnostics.add(delivered=len(samples))
            for sample in samples:
                for callback in self._callbacks:
                    callback(sample)
        return samples

    def start(self) -> None:
        """Poll in a daemon thread until :meth:`close` (or a fatal error)."""
        if self._thread is not None:
            raise RuntimeError('driver already started')
        self._thread = threading.Thread(target=self._spin, name=type(self).__name__, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            try:
                self.poll(self.poll_timeout)
            except Exception as error:  # noqa: BLE001 - any failure must make the device safe
                if not isinstance(error, ConnectionError):   # a lost link needs no traceback
                    log.exception('%s stopped on a fatal error', type(self).__name__)
                self.fatal_error = error
                self._event(logging.ERROR, f'{type(self).__name__} stopped: {error}')
                self._on_fatal(error)
                return

    def latest(self) -> SampleT | None:
        """The most recent sample, or None before the first."""
        return self._latest

    def wait_for_samples(self, count: int, timeout: float) -> bool:
        """Block until ``count`` more samples have been delivered (background mode); False on
        timeout."""
        with self._new_sample:
            target = self._count + count
            return self._new_sample.wait_for(lambda: self._count >= target, timeout)

    def is_stale(self) -> bool:
        """True when nothing arrived for longer than ``stale_after`` seconds."""
        return self.diagnostics.age() > self.stale_after

    def close(self) -> None:
        """Make the device safe (``_before_stop``), stop the thread, release the transport
        (``_shutdown``). Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._before_stop()
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._shutdown()

    def __enter__(self):
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
