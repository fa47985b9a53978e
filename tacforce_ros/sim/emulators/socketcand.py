"""A minimal socketcand server (raw mode) on 127.0.0.1: a CAN bus other processes reach with
python-can's ``socketcand`` interface.

Protocol as python-can 4.6's client speaks it (read from its source): the server greets with
``< hi >``; ``< open CHANNEL >`` and ``< rawmode >`` are each answered by a separate ``< ok >``;
frames to clients are ``< frame ID SEC.USEC HEXDATA >`` (data unspaced), frames from clients are
``< send ID LEN b b ... >`` (hex bytes). No RTR frames exist on this transport.
"""
from __future__ import annotations

import select
import socket
import threading
import time
from collections import deque
from collections.abc import Callable

import can

from tacforce_ros.devices.diagnostics import LinkDiagnostics
from tacforce_ros.sim.emulators.base import LOOPBACK, require_loopback

# A client joins the bus once it sent its first frame, or after this grace time: frames sent
# earlier could share one TCP read with the final '< ok >', which python-can's handshake rejects.
JOIN_GRACE_S = 0.2
# Bus frames waiting for a client that does not read, at most; later ones are dropped for it,
# counted. socketcand serves each client from its own process, which blocks in its send while the
# client does not read; the CAN socket's receive queue behind it then overflows and the kernel
# drops frames: the client loses frames, not its connection. The queue's length is our estimate
# of that socket's: net.core.rmem_default (212,992 bytes) over about 1 kB per queued CAN frame.
CLIENT_QUEUE_FRAMES = 200


def format_frame(message: can.Message) -> bytes:
    """``< frame 080 12.345678 0102... >`` for one received frame."""
    width = 8 if message.is_extended_id else 3
    stamp = message.timestamp or time.time()
    return (f'< frame {message.arbitration_id:0{width}X} {stamp:.6f} '
            f'{bytes(message.data).hex().upper()} >').encode('ascii')


def parse_send(command: str) -> can.Message:
    """Parse ``send ID LEN b ...`` (without the angle brackets); ValueError if inconsistent."""
    fields = command.split()
    if len(fields) < 3 or fields[0] != 'send':
        raise ValueError(f'not a send command: {command!r}')
    length = int(fields[2], 16)
    data = bytes(int(b, 16) for b in fields[3:])
    if len(data) != length:
        raise ValueError(f'send with length {length} carries {len(data)} bytes')
    return can.Message(arbitration_id=int(fields[1], 16), data=data, dlc=length,
                       is_extended_id=len(fields[1]) > 3, timestamp=time.time())


class _Client:
    """One TCP client. Its own thread writes to it, blocking while the client does not read (as
    socketcand's process for it does); the bus's frames queue for it meanwhile, up to
    CLIENT_QUEUE_FRAMES, and the rest are dropped (the server counts them)."""

    def __init__(self, sock: socket.socket, on_gone: Callable[[_Client], None]) -> None:
        self.sock = sock
        self.joined_at = float('inf')     # monotonic time from which it receives bus frames
        self.rawmode_at: float | None = None
        self._on_gone = on_gone
        self._queue: deque[tuple[bytes, int]] = deque()    # (payload, bus frames in it)
        self._queued_frames = 0
        self._ready = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._send_loop, daemon=True)
        self._thread.start()

    def reply(self, payload: bytes) -> None:
        """A reply to the client's own command: never dropped."""
        self._put(payload, 0)

    def deliver(self, payload: bytes, frames: int) -> int:
        """Bus frames for the client; returns how many were dropped (its queue full)."""
        with self._ready:
            if self._queued_frames + frames > CLIENT_QUEUE_FRAMES:
                return frames
        self._put(payload, frames)
        return 0

    def _put(self, payload: bytes, frames: int) -> None:
        with self._ready:
            if self._closed:
                return
            self._queue.append((payload, frames))
            self._queued_frames += frames
            self._ready.notify()

    def _send_loop(self) -> None:
        while True:
            with self._ready:
                while not self._queue and not self._closed:
                    self._ready.wait()
                if self._closed:
                    return
                payload, frames = self._queue.popleft()
            try:
                self.sock.sendall(payload)
            except OSError:
                self._on_gone(self)
                return
            with self._ready:
                self._queued_frames -= frames

    def close(self) -> None:
        """End its thread and its connection (a blocked send returns at the shutdown)."""
        with self._ready:
            self._closed = True
            self._ready.notify()
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass                # already gone
        self.sock.close()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)


class SocketcandServer:
    """One CAN channel served over TCP. Frames a client sends go to ``on_frame`` (the device)
    and to the other clients, as on a shared bus; :meth:`broadcast` puts device frames on it."""

    def __init__(self, on_frame: Callable[[can.Message], None], host: str = LOOPBACK,
                 port: int = 0, channel: str = 'can0') -> None:
        self.on_frame = on_frame
        self.channel = channel
        self.diagnostics = LinkDiagnostics()
        self._listener = socket.create_server((require_loopback(host), port))
        self._listener.settimeout(0.1)
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._accept, daemon=True)]
        self._threads[0].start()

    @property
    def address(self) -> tuple[str, int]:
        return self._listener.getsockname()

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._clients)

    def broadcast(self, messages: list[can.Message], exclude: _Client | None = None) -> None:
        """Deliver frames to every joined client, in one write each; a client whose queue is
        full loses them (counted as dropped)."""
        payload = b''.join(format_frame(m) for m in messages)
        now = time.monotonic()
        with self._lock:
            clients = [c for c in self._clients if c is not exclude and c.joined_at <= now]
        for client in clients:
            lost = client.deliver(payload, len(messages))
            if lost:
                self.diagnostics.add(dropped=lost)

    def _drop(self, client: _Client) -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)
        client.close()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                sock, _ = self._listener.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(None)      # its writer blocks as socketcand's does; reads poll
            thread = threading.Thread(target=self._serve, args=(_Client(sock, self._drop),),
                                      daemon=True)
            self._threads.append(thread)
            thread.start()

    def _serve(self, client: _Client) -> None:
        with self._lock:
            self._clients.append(client)
        client.reply(b'< hi >')
        buffer = ''
        try:
            while not self._stop.is_set():
                readable, _, _ = select.select([client.sock], [], [], 0.1)
                if not readable:
                    if (client.rawmode_at is not None
                            and time.monotonic() - client.rawmode_at >= JOIN_GRACE_S):
                        client.joined_at = min(client.joined_at, time.monotonic())
                    continue
                chunk = client.sock.recv(4096)
                if not chunk:
                    return
                buffer += chunk.decode('ascii', errors='replace')
                while (end := buffer.find('>')) != -1:
                    start = buffer.find('<')
                    command = buffer[start + 1:end].strip() if 0 <= start < end else ''
                    buffer = buffer[end + 1:]
                    self._handle(client, command)
        except (OSError, ValueError):      # reset, or closed by its writer (select: fd -1)
            return
        finally:
            self._drop(client)

    def _handle(self, client: _Client, command: str) -> None:
        if command.startswith('open '):
            known = command[5:].strip() == self.channel
            client.reply(b'< ok >' if known else b'< error unknown channel >')
        elif command == 'rawmode':
            client.rawmode_at = time.monotonic()
            client.reply(b'< ok >')
        elif command.startswith('send'):
            self.diagnostics.note_received()
            try:
                message = parse_send(command)
            except ValueError as error:
                self.diagnostics.note_malformed(str(error))
                return
            client.joined_at = min(client.joined_at, time.monotonic())
            self.broadcast([message], exclude=client)
            self.on_frame(message)
        else:
            self.diagnostics.note_malformed(f'unsupported socketcand command {command!r}')

    def close(self) -> None:
        self._stop.set()
        self._listener.close()
        for thread in self._threads:
            thread.join(timeout=2.0)
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            client.close()
