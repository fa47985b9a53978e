"""Helpers for the device tests: bounded waiting on a condition, a relay that can hang."""
from __future__ import annotations

import select
import socket
import threading
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


class Relay:
    """A TCP relay on loopback between clients and `target`: what a client sends goes to its own
    connection to the target, and back. freeze() stops it forwarding either way with every
    socket kept open: a link, or a device, that hangs. `buffer` (bytes) shrinks the relay's
    socket buffers so that a client that keeps sending to a frozen relay fills them soon.
    `piece` (bytes) passes what the target sends on in pieces that size, each its own TCP
    segment (`pause` s apart), so that the client's reads end mid-message."""

    def __init__(self, target: tuple[str, int], buffer: int | None = None,
                 piece: int | None = None, pause: float = 0.0003) -> None:
        self.target, self.buffer, self.piece, self.pause = target, buffer, piece, pause
        self.listener = socket.create_server(('127.0.0.1', 0))
        self.listener.settimeout(0.05)
        self.address = self.listener.getsockname()
        self.frozen = threading.Event()
        self._stop = threading.Event()
        self._sockets: list[socket.socket] = []
        self._threads = [threading.Thread(target=self._accept, daemon=True)]
        self._threads[0].start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self.listener.accept()
            except (TimeoutError, OSError):
                continue
            server = socket.create_connection(self.target)
            for sock in (client, server):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                if self.buffer is not None:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.buffer)
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.buffer)
                self._sockets.append(sock)
            for source, sink, piece in ((client, server, None), (server, client, self.piece)):
                thread = threading.Thread(target=self._pump, args=(source, sink, piece),
                                          daemon=True)
                self._threads.append(thread)
                thread.start()

    def _pump(self, source: socket.socket, sink: socket.socket, piece: int | None) -> None:
        while not self._stop.is_set():
            if self.frozen.is_set():
                time.sleep(0.01)
                continue
            readable, _, _ = select.select([source], [], [], 0.05)
            if not readable:
                continue
            try:
                data = source.recv(65536)
                if not data:
                    sink.shutdown(socket.SHUT_WR)
                    return
                for start in range(0, len(data), piece or len(data)):
                    sink.sendall(data[start:start + (piece or len(data))])
                    if piece:
                        time.sleep(self.pause)
            except OSError:
                return

    def freeze(self) -> None:
        self.frozen.set()

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5.0)
        for sock in [self.listener, *self._sockets]:
            sock.close()

    def __enter__(self) -> Relay:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
