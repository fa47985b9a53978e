"""xela_server on 127.0.0.1: a WebSocket server sending a welcome frame, then v1.8 routine
frames at a fixed rate from ``frame_source() -> (counts (368, 3) uint16, temps (368,) K,
server time s)``: the server's clock is whatever the source says (the host's Unix time for a
stand-alone server, simulated time behind a simulator, whose world the server lives in)."""
from __future__ import annotations

import queue
import threading
import time
from collections import deque
from collections.abc import Callable

import numpy as np
from websockets.exceptions import ConnectionClosed
from websockets.sync.server import Server, ServerConnection, serve

from tacforce_ros.devices.xela import routine_message, welcome_message
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.sim.emulators.base import LOOPBACK, Pacer, require_loopback

FrameSource = Callable[[], tuple[np.ndarray, np.ndarray, float]]


class XelaServerEmulator:
    """Serves every connected client the same frames; the ``message`` counter is global.

    Fault hooks: :meth:`inject_text` (send any text, e.g. malformed JSON or a frame with the
    wrong taxel count), :meth:`stop` / :meth:`start` (the server disappears and comes back on
    the same port). ``sent_log`` keeps (message, monotonic send time) for latency measurement.
    """

    def __init__(self, frame_source: FrameSource, host: str = LOOPBACK, port: int = 0,
                 rate_hz: float = RATE_HZ, model: str = 'XR23AHRCPP',
                 log_length: int = 100_000) -> None:
        self.frame_source = frame_source
        self.host = require_loopback(host)
        self.port = port
        self.rate_hz = rate_hz
        self.model = model
        self.sent_log: deque[tuple[int, float]] = deque(maxlen=log_length)
        self._sequence = 0
        self._lock = threading.Lock()
        self._injected: list[queue.SimpleQueue[str]] = []
        self._server: Server | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.start()

    @property
    def address(self) -> tuple[str, int]:
        return self.host, self.port

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._injected)      # one pending queue per connected client

    @property
    def url(self) -> str:
        return f'ws://{self.host}:{self.port}'

    def start(self) -> None:
        """Listen (again) on the same port."""
        if self._server is not None:
            return
        self._stop.clear()
        self._server = serve(self._handle, self.host, self.port, compression=None)
        self.port = self._server.socket.getsockname()[1]
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Close the listening socket and every connection (the server disappears)."""
        if self._server is None:
            return
        self._stop.set()
        self._server.shutdown()
        self._thread.join(timeout=5.0)
        self._server = self._thread = None

    def inject_text(self, text: str) -> None:
        """Send ``text`` as the next frame to every connected client."""
        with self._lock:
            for pending in self._injected:
                pending.put(text)

    def _next_message(self) -> str:
        counts, temperatures, server_time = self.frame_source()
        with self._lock:
            self._sequence += 1
            sequence = self._sequence
        text = routine_message(sequence, counts, temperatures, server_time, self.model)
        self.sent_log.append((sequence, time.monotonic()))
        return text

    def _handle(self, connection: ServerConnection) -> None:
        pending: queue.SimpleQueue[str] = queue.SimpleQueue()
        with self._lock:
            self._injected.append(pending)
        pacer = Pacer(self.rate_hz)
        try:
            connection.send(welcome_message())
            while pacer.wait(self._stop):
                while not pending.empty():
                    connection.send(pending.get())
                connection.send(self._next_message())
        except ConnectionClosed:
            pass      # the client left
        finally:
            with self._lock:
                self._injected.remove(pending)

    def close(self) -> None:
        self.stop()

    def __enter__(self) -> XelaServerEmulator:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
