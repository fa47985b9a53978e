"""A Net F/T box on 127.0.0.1: answers RDT requests and streams records at a fixed rate."""
from __future__ import annotations

import socket
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np

from tacforce_ros.devices.diagnostics import LinkDiagnostics
from tacforce_ros.devices.netft import (CMD_RESET_LATCH, CMD_SET_BIAS, CMD_START_BUFFERED,
                                        CMD_START_REALTIME, CMD_STOP, RdtError, decode_request,
                                        encode_records)
from tacforce_ros.sim.emulators.base import LOOPBACK, Pacer, require_loopback

WrenchSource = Callable[[], tuple[np.ndarray, int]]    # -> (counts int32 (6,), status uint32)


class NetFtEmulator:
    """RDT responder: ``wrench_source()`` is sampled once per record.

    Both counters start at ``first_sequence`` and wrap at 2**32. Requests with a wrong header or
    length are ignored and counted in ``diagnostics.malformed``, as the box ignores them. Fault
    hooks (``send_raw``, ``skip``, ``reorder_next``, ``set_sequence``) act on the stream to the
    current client. ``sent_log`` keeps (rdt_sequence, monotonic send time) for latency
    measurements.
    """

    def __init__(self, wrench_source: WrenchSource, host: str = LOOPBACK, port: int = 0,
                 rate_hz: float = 1000.0, first_sequence: int = 1, log_length: int = 100_000):
        self.wrench_source = wrench_source
        self.rate_hz = rate_hz
        self.diagnostics = LinkDiagnostics()
        self.sent_log: deque[tuple[int, float]] = deque(maxlen=log_length)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((require_loopback(host), port))
        self._sock.settimeout(0.05)
        self._lock = threading.Lock()
        self._client: tuple[str, int] | None = None
        self._remaining = 0               # records left to send, -1 = until stopped
        self._sequence = first_sequence
        self._bias = np.zeros(6, dtype=np.int64)
        self._skip = 0
        self._held: bytes | None = None
        self._reorder = False
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._serve_requests, daemon=True),
                         threading.Thread(target=self._stream, daemon=True)]
        for thread in self._threads:
            thread.start()

    @property
    def address(self) -> tuple[str, int]:
        return self._sock.getsockname()

    @property
    def streaming(self) -> bool:
        return self._client is not None and self._remaining != 0

    def _serve_requests(self) -> None:
        while not self._stop.is_set():
            try:
                payload, peer = self._sock.recvfrom(64)
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return            # socket closed
            self.diagnostics.note_received()
            try:
                command, count = decode_request(payload)
            except RdtError as error:
                self.diagnostics.note_malformed(str(error))
                continue
            with self._lock:
                if command in (CMD_START_REALTIME, CMD_START_BUFFERED):
                    self._client, self._remaining = peer, (count if count else -1)
                elif command == CMD_STOP:
                    self._remaining = 0
                elif command == CMD_SET_BIAS:
                    self._bias = np.asarray(self.wrench_source()[0], dtype=np.int64)
                elif command != CMD_RESET_LATCH:
                    self.diagnostics.note_malformed(f'unknown RDT command 0x{command:04x}')

    def _stream(self) -> None:
        pacer = Pacer(self.rate_hz)
        while pacer.wait(self._stop):
            with self._lock:
                if self._client is None or self._remaining == 0:
                    continue
                counts, status = self.wrench_source()
                unbiased = np.clip(np.asarray(counts, dtype=np.int64) - self._bias,
                                   -2**31, 2**31 - 1)
                sequence = self._sequence
                self._sequence = (sequence + 1) & 0xFFFFFFFF
                self._remaining -= self._remaining > 0
                if self._skip:
                    self._skip -= 1
                    continue
                record = encode_records(sequence, sequence, status, unbiased)
                if self._reorder:
                    self._reorder, self._held = False, record
                    continue
                outgoing = [record] + ([self._held] if self._held is not None else [])
                self._held = None
                client = self._client
            for datagram in outgoing:
                self.sent_log.append((int.from_bytes(datagram[:4], 'big'), time.monotonic()))
                self._send(datagram, client)

    def _send(self, payload: bytes, client: tuple[str, int]) -> None:
        try:
            self._sock.sendto(payload, client)
        except OSError:
            pass      # client went away; UDP has nobody to tell

    # --- fault injection -------------------------------------------------------------------
    def send_raw(self, payload: bytes) -> None:
        """Send an arbitrary datagram (truncated, oversized ...) to the current client."""
        with self._lock:
            client = self._client
        if client is None:
            raise RuntimeError('no client has requested a stream yet')
        self._send(payload, client)

    def skip(self, count: int) -> None:
        """Lose the next ``count`` records on the wire (their sequence numbers are used up)."""
        with self._lock:
            self._skip += count

    def reorder_next(self) -> None:
        """Send the next record after the one that follows it."""
        with self._lock:
            self._reorder = True

    def set_sequence(self, sequence: int) -> None:
        """Continue numbering at ``sequence`` (e.g. 2**32 - 2 to exercise the wrap)."""
        with self._lock:
            self._sequence = sequence & 0xFFFFFFFF

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._sock.close()

    def __enter__(self) -> NetFtEmulator:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
