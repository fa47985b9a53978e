"""The emulated socketcand server and a client that does not read: as socketcand, whose process
for the client blocks in its send while the CAN socket behind it overflows, the client loses
bus frames (counted) but keeps its connection, and its own commands still reach the bus. The
server used to drop such a client after a 0.1 s write; an Allegro driver's servo-off then went
to a closed connection."""
import socket
import time

import can
from devices_support import wait_until

from tacforce_ros.sim.emulators.socketcand import CLIENT_QUEUE_FRAMES, SocketcandServer

FRAMES_PER_WRITE = 100
WRITES = 3000            # ~12 MB of frame lines, far more than the sockets' buffers hold
CLIENT_BUFFER = 1 << 14  # bytes: the client's receive buffer, fixed (no autotuning)


def _expect(sock: socket.socket, text: bytes) -> None:
    received = b''
    deadline = time.monotonic() + 5.0
    while text not in received and time.monotonic() < deadline:
        received += sock.recv(4096)
    assert text in received


def test_a_client_that_does_not_read_loses_frames_not_its_connection():
    bus = []
    server = SocketcandServer(bus.append)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, CLIENT_BUFFER)
    sock.settimeout(5.0)
    try:
        sock.connect(server.address)
        _expect(sock, b'< hi >')
        sock.sendall(b'< open can0 >')
        _expect(sock, b'< ok >')
        sock.sendall(b'< rawmode >')
        _expect(sock, b'< ok >')
        sock.sendall(b'< send 123 1 AA >')        # joins the bus at its first frame
        assert wait_until(lambda: len(bus) == 1)
        frame = can.Message(arbitration_id=0x456, data=bytes(8), is_extended_id=False)
        for _ in range(WRITES):                   # the client reads none of it meanwhile
            server.broadcast([frame] * FRAMES_PER_WRITE)
        dropped = server.diagnostics.snapshot().dropped
        assert dropped > 0 and server.client_count == 1
        sock.sendall(b'< send 124 1 BB >')
        assert wait_until(lambda: [m.arbitration_id for m in bus] == [0x123, 0x124])
        # What was queued arrives whole: every frame line, none cut.
        received, total = b'', WRITES * FRAMES_PER_WRITE
        sock.settimeout(1.0)
        while received.count(b'< frame 456 ') + dropped < total:
            chunk = sock.recv(1 << 16)
            assert chunk, 'the server closed the connection'
            received += chunk
        assert received.count(b'< frame 456 ') + dropped == total
        assert received.count(b'<') == received.count(b'>')
        assert dropped % FRAMES_PER_WRITE == 0 and dropped <= total - CLIENT_QUEUE_FRAMES
    finally:
        sock.close()
        server.close()
