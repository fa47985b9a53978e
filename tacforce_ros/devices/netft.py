"""ATI Net F/T Raw Data Transfer (RDT) over UDP: request/record codec and a streaming client.

Wire facts (docs/PROTOCOLS.md section 3, from netft/netft-docs): requests are 8 bytes big-endian
(uint16 0x1234, uint16 command, uint32 sample count, 0 = infinite); records are 36 bytes
big-endian (uint32 rdt_sequence, uint32 ft_sequence, uint32 status, 6 x int32 counts).
Counts-per-unit and unit names are device configuration (cfgcpf/cfgcpt, scfgfu/scfgtu): they are
read from our config, never assumed; the defaults (1e6 counts per N and per N-m) are the typical
values only.
"""
from __future__ import annotations

import logging
import socket
import struct
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from tacforce_ros.devices.diagnostics import ArrivalStamp, sequence_delta
from tacforce_ros.devices.polling import PollingDriver

RDT_PORT = 49152
RDT_HEADER = 0x1234
CMD_STOP = 0x0000
CMD_START_REALTIME = 0x0002
CMD_START_BUFFERED = 0x0003
CMD_RESET_LATCH = 0x0041
CMD_SET_BIAS = 0x0042
STATUS_MONITOR_WARNING = 0x80010000
# A start request refused (ICMP port unreachable: no box there yet) is sent again this often, s;
# one that nothing answered (the datagram lost, or its refusal never reported: the kernel may
# withhold ICMP) after SILENT_RETRY_S. The box streams from the first request it gets.
REFUSED_RETRY_S = 0.1
SILENT_RETRY_S = 0.5

REQUEST = struct.Struct('>HHI')
RECORD = struct.Struct('>III6i')
RECORD_DTYPE = np.dtype([('rdt_sequence', '>u4'), ('ft_sequence', '>u4'), ('status', '>u4'),
                         ('counts', '>i4', (6,))])
assert RECORD.size == RECORD_DTYPE.itemsize == 36

# SI value of one configured unit (exact NIST definitions: 1 lbf = 4.4482216152605 N,
# 1 kgf = 9.80665 N, 1 in = 0.0254 m). Names as the Net F/T web page lists them.
FORCE_UNITS_SI = {'N': 1.0, 'kN': 1e3, 'lbf': 4.4482216152605, 'klbf': 4448.2216152605,
                  'kgf': 9.80665, 'gf': 9.80665e-3}
TORQUE_UNITS_SI = {'N-m': 1.0, 'Nm': 1.0, 'N-mm': 1e-3, 'Nmm': 1e-3, 'kN-m': 1e3,
                   'lbf-in': 4.4482216152605 * 0.0254, 'lbf-ft': 4.4482216152605 * 0.3048,
                   'kgf-cm': 9.80665e-2, 'gf-cm': 9.80665e-5}


class RdtError(ValueError):
    """A datagram or request that does not follow RDT."""


def encode_request(command: int, sample_count: int = 0) -> bytes:
    """8-byte request; ``encode_request(CMD_START_REALTIME)`` is ``12 34 00 02 00 00 00 00``."""
    return REQUEST.pack(RDT_HEADER, command, sample_count)


def decode_request(payload: bytes) -> tuple[int, int]:
    """(command, sample_count) of a request; RdtError on a wrong length or header."""
    if len(payload) != REQUEST.size:
        raise RdtError(f'request is {len(payload)} bytes, expected {REQUEST.size}')
    header, command, count = REQUEST.unpack(payload)
    if header != RDT_HEADER:
        raise RdtError(f'request header 0x{header:04x}, expected 0x{RDT_HEADER:04x}')
    return command, count


def encode_records(rdt_sequence: int, ft_sequence: int, status: int,
                   counts: np.ndarray) -> bytes:
    """One 36-byte record (counters wrap at 2**32)."""
    return RECORD.pack(rdt_sequence & 0xFFFFFFFF, ft_sequence & 0xFFFFFFFF, status & 0xFFFFFFFF,
                       *(int(c) for c in np.asarray(counts, dtype=np.int32)))


def decode_records(payload: bytes) -> np.ndarray:
    """All records of a datagram as a structured array; RdtError unless the length is a
    non-zero multiple of 36."""
    if not payload or len(payload) % RECORD.size:
        raise RdtError(f'datagram of {len(payload)} bytes is not a multiple of {RECORD.size}')
    return np.frombuffer(payload, dtype=RECORD_DTYPE)


def status_severity(status: int) -> str:
    """'ok', 'warning' (0x80010000, monitor warning) or 'serious' (any other non-zero word)."""
    if status == 0:
        return 'ok'
    return 'warning' if status == STATUS_MONITOR_WARNING else 'serious'


@dataclass(frozen=True)
class NetFtConfig:
    """Connection and scaling. ``counts_per_force``/``counts_per_torque`` and the unit names
    must match the box's cfgcpf/cfgcpt and scfgfu/scfgtu (see its /netftapi2.xml)."""

    host: str = '192.168.1.1'
    port: int = RDT_PORT
    counts_per_force: float = 1_000_000.0
    counts_per_torque: float = 1_000_000.0
    force_unit: str = 'N'
    torque_unit: str = 'N-m'
    stale_after: float = 0.05
    bias_window: int = 100        # samples averaged by set_host_bias()

    def __post_init__(self) -> None:
        if self.force_unit not in FORCE_UNITS_SI:
            raise ValueError(f'force_unit {self.force_unit!r} not one of {sorted(FORCE_UNITS_SI)}')
        if self.torque_unit not in TORQUE_UNITS_SI:
            raise ValueError(
                f'torque_unit {self.torque_unit!r} not one of {sorted(TORQUE_UNITS_SI)}')
        if not (self.counts_per_force > 0 and self.counts_per_torque > 0):
            raise ValueError('counts_per_force and counts_per_torque must be positive')

    def si_per_count(self) -> np.ndarray:
        """(6,) float64 factors from counts to N (forces) and N m (torques)."""
        force = FORCE_UNITS_SI[self.force_unit] / self.counts_per_force
        torque = TORQUE_UNITS_SI[self.torque_unit] / self.counts_per_torque
        return np.array([force] * 3 + [torque] * 3, dtype=np.float64)


@dataclass(frozen=True)
class WrenchSample:
    """One RDT record: ``wrench`` (6,) float64 [Fx Fy Fz N, Tx Ty Tz N m], host bias removed."""

    rdt_sequence: int
    ft_sequence: int
    status: int
    counts: np.ndarray
    wrench: np.ndarray
    stamp: ArrivalStamp


class NetFtClient(PollingDriver[WrenchSample]):
    """Streams real-time RDT records from one Net F/T box; always sends stop on close.

    Records older than the newest delivered one (signed uint32 sequence difference <= 0) are
    counted as reordered and dropped; forward jumps add the missing count to ``gaps``. A record
    with a monitor warning (0x80010000) is delivered with its status and counted as a warning;
    one with any other non-zero status word is withheld: counted in ``status_errors`` and
    ``dropped``, kept out of the bias window, and reported by an ERROR event when such records
    start (and an INFO event when healthy records return), since its numbers cannot be trusted.
    """

    def __init__(self, config: NetFtConfig) -> None:
        super().__init__(config.stale_after)
        self.config = config
        self._scale = config.si_per_count()
        self._host_bias = np.zeros(6, dtype=np.float64)
        self._recent = deque(maxlen=config.bias_window)
        self._last_sequence: int | None = None
        self._withholding = 0       # serious-status records withheld since the last good one
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.connect((config.host, config.port))
        self._requested = time.monotonic()      # when the start request last went out
        self._refused = False                   # ... and was refused
        self._answered = False                  # a datagram came since the first request
        self.start_requests = 1
        self._send(CMD_START_REALTIME)

    def _send(self, command: int, sample_count: int = 0) -> None:
        self._sock.send(encode_request(command, sample_count))

    def bias_device(self) -> None:
        """Ask the box to zero itself (software bias, command 0x42; no reply)."""
        self._send(CMD_SET_BIAS)

    def set_host_bias(self) -> np.ndarray:
        """Subtract, from now on, the mean of the last ``bias_window`` raw wrenches; returns it."""
        if not self._recent:
            raise RuntimeError('no wrench received yet: nothing to bias against')
        self._host_bias = np.mean(np.asarray(self._recent), axis=0)
        return self._host_bias.copy()

    def clear_host_bias(self) -> None:
        self._host_bias = np.zeros(6, dtype=np.float64)

    def _receive(self, timeout: float) -> list[WrenchSample]:
        waited = time.monotonic() - self._requested
        if not self._answered and waited >= (REFUSED_RETRY_S if self._refused
                                             else SILENT_RETRY_S):
            self._refused = False
            self._requested = time.monotonic()
            self.start_requests += 1
            try:
                self._send(CMD_START_REALTIME)
            except OSError:
                self._refused = True        # still nobody there
        self._sock.settimeout(timeout if timeout > 0 else 0.0)
        samples: list[WrenchSample] = []
        while True:
            try:
                payload = self._sock.recv(65536)
            except (BlockingIOError, TimeoutError, socket.timeout):
                return samples
            except ConnectionRefusedError:
                # ICMP port unreachable from a previous send: the box is not (yet) there. RDT
                # streams only when asked, so ask again: a box coming up (a simulator started
                # beside us) streams within REFUSED_RETRY_S of listening.
                self.diagnostics.last_error = 'connection refused by the F/T address'
                self._refused = True
                return samples
            stamp = ArrivalStamp.now()
            self._answered = True
            self.diagnostics.note_received(stamp.monotonic)
            try:
                records = decode_records(payload)
            except RdtError as error:
                self.diagnostics.note_malformed(str(error))
            else:
                samples.extend(self._accept(records, stamp))
            self._sock.settimeout(0.0)    # drain what is queued without waiting again

    def _accept(self, records: np.ndarray, stamp: ArrivalStamp) -> list[WrenchSample]:
        accepted = []
        for record in records:
            sequence = int(record['rdt_sequence'])
            if self._last_sequence is not None:
                delta = sequence_delta(sequence, self._last_sequence)
                if delta <= 0:
                    self.diagnostics.add(reordered=1, dropped=1)
                    continue
                if delta > 1:
                    self.diagnostics.add(gaps=delta - 1)
            self._last_sequence = sequence
            status = int(record['status'])
            severity = status_severity(status)
            if severity == 'serious':
                self.diagnostics.add(status_errors=1, dropped=1)
                if not self._withholding:
                    self._event(logging.ERROR, f'F/T status 0x{status:08x} (record '
                                f'{sequence}): withholding records until the status clears')
                self._withholding += 1
                continue
            if self._withholding:
                self._event(logging.INFO, f'F/T status clear again after {self._withholding} '
                            'withheld records')
                self._withholding = 0
            if severity == 'warning':
                self.diagnostics.add(status_warnings=1)
            counts = record['counts'].astype(np.int32)
            raw = counts * self._scale
            self._recent.append(raw)
            accepted.append(WrenchSample(sequence, int(record['ft_sequence']), status, counts,
                                         raw - self._host_bias, stamp))
        return accepted

    def _shutdown(self) -> None:
        try:
            self._send(CMD_STOP)
        except OSError:
            pass    # the box is gone: nothing left to stop
        finally:
            self._sock.close()
