"""python-can's socketcand client (4.6, pinned), made safe to stop: one bounded connect, a
kernel send timeout, a closed connection told from a quiet one, and its partial-read warnings
counted instead of logged. The Allegro driver's link to a socketcand server (the emulator's, or
a real bus behind socketcand)."""
from __future__ import annotations

import logging
import socket
import struct
import threading

import can
from can.interfaces.socketcand import socketcand as _socketcand_module

from tacforce_ros.devices.allegro_codec import AllegroError


class SocketcandLogFilter(logging.Filter):
    """Keeps python-can's socketcand client from flooding the log with "Got incomplete message
    => waiting for more data": one TCP read ending mid-frame, which the client keeps and
    completes with the next read (no frame is lost:
    test/devices/test_devices_socketcand_fragments.py); at 1333 frames/s it was hundreds of
    lines a minute. Its other warnings (discarded data) pass; `suppressed` counts what was
    dropped. (Its flood of connect failures cannot happen: open_bus connects once.)"""

    PARTIAL_READ = 'Got incomplete message => waiting for more data'

    def __init__(self) -> None:
        super().__init__()
        self.suppressed = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage() == self.PARTIAL_READ:
            self.suppressed += 1
            return False
        return True


SOCKETCAND_LOG = SocketcandLogFilter()
SOCKETCAND_LOGGER = 'can.interfaces.socketcand.socketcand'


# Longest wait on the socketcand server for one socket operation (connect, its greeting, a
# frame sent): a server that is gone or stopped answering must not hold the driver.
SOCKETCAND_TIMEOUT_S = 0.5
_CONNECTING = threading.Lock()     # one socketcand bus made at a time (see open_bus)


def _connect_once(sock: socket.socket, host: str, port: int) -> None:
    sock.settimeout(SOCKETCAND_TIMEOUT_S)       # the greeting's wait too
    sock.connect((host, port))


def open_bus(config) -> can.BusABC:
    """The python-can bus of `config`; for socketcand with every socket operation bounded.

    python-can 4.6's socketcand client retries a refused connection for 10 s without a pause,
    and waits for the server's greeting, and sends, without a timeout: a driver asked to stop
    then stayed 10 s, or for ever with a server that accepts and never answers (bench_stop). So
    its connect is made one attempt, on a socket with SOCKETCAND_TIMEOUT_S as its timeout, for
    the making of the bus (python-can's connect_to_server, swapped while a lock is held, and put
    back); then the socket is left blocking (the driver peeks at it without waiting, which a
    socket timeout would turn into a wait) with SOCKETCAND_TIMEOUT_S as the kernel's send
    timeout: a send the server does not take fails with BlockingIOError."""
    kwargs = dict(config.bus_kwargs)
    if config.interface != 'socketcand':
        return can.Bus(interface=config.interface, channel=config.channel, **kwargs)
    where = f'{kwargs.get("host")}:{kwargs.get("port")}'
    with _CONNECTING:
        python_cans = _socketcand_module.connect_to_server
        _socketcand_module.connect_to_server = _connect_once
        try:
            bus = can.Bus(interface='socketcand', channel=config.channel, **kwargs)
        except TimeoutError as error:
            raise AllegroError(f'the socketcand server at {where} did not answer within '
                               f'{SOCKETCAND_TIMEOUT_S} s') from error
        except OSError as error:
            raise AllegroError(f'no socketcand server at {where}: {error}') from None
        finally:
            _socketcand_module.connect_to_server = python_cans
    sock = socketcand_socket(bus)
    sock.settimeout(None)
    seconds = int(SOCKETCAND_TIMEOUT_S)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO,
                    struct.pack('ll', seconds, int((SOCKETCAND_TIMEOUT_S - seconds) * 1e6)))
    return bus


def socketcand_socket(bus: can.BusABC) -> socket.socket | None:
    """The TCP socket of python-can's socketcand client, None for other interfaces. That client
    (python-can 4.6, pinned) reads a closed connection as "no data yet": recv() returns b'' and
    it polls on until the timeout, at 100 % CPU and with no error, so the driver looks for the
    end of the stream itself."""
    return getattr(bus, '_SocketCanDaemonBus__socket', None)


def peer_closed(sock: socket.socket) -> bool:
    """True when the peer closed or reset the TCP connection (reads nothing)."""
    try:
        return sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b''
    except BlockingIOError:
        return False            # open, nothing to read
    except OSError:
        return True             # reset, or the socket is closed
