"""Allegro Hand V4 over CAN (python-can, any interface): frame codec and a torque driver.

Wire facts (docs/PROTOCOLS.md section 2, from simlabrobotics/allegro_hand_ros_v4 and Wonik's
ROS 2 SDK): standard ids ``(command << 2) | device``, little-endian payloads, positions in
encoder counts of 333.3/65536 degrees, torques as int16 PWM = tau[Nm] * 1200 on V4 (800 on older
8 V hands: ``pwm_per_nm``). HAND_INFO/SERIAL are requested with remote (RTR) frames on a real bus;
transports that cannot carry RTR (python-can's socketcand client) need ``rtr_requests=False``,
which sends zero-length data frames instead. The TEMPERATURE frame layout is uncertain.
"""
from __future__ import annotations

import logging
import math
import struct
import time
from dataclasses import dataclass, field

import can
import numpy as np

from tacforce_ros.devices.diagnostics import ArrivalStamp
from tacforce_ros.devices.polling import PollingDriver

N_FINGERS = 4
N_JOINTS = 16
CMD_SYSTEM_ON = 0x40
CMD_SYSTEM_OFF = 0x41
CMD_FINGER_POSE = 0x20          # + finger
CMD_TEMPERATURE = 0x38          # + finger (payload layout uncertain)
CMD_SET_TORQUE = 0x60           # + finger
CMD_HAND_INFO = 0x80
CMD_SET_PERIOD = 0x81
CMD_SERIAL = 0x88

RAD_PER_COUNT = 333.3 / 65536.0 * math.pi / 180.0
PWM_PER_NM_V4 = 1200.0
PWM_PER_NM_8V = 800.0
# Firmware per-joint torque clamps [Nm], joints 0-3 of index, middle, ring, then thumb.
FIRMWARE_TORQUE_LIMITS = np.array([0.3125, 0.5625, 0.375, 0.2375] * 3
                                  + [0.4375, 0.3375, 0.225, 0.225], dtype=np.float64)

POSE = struct.Struct('<4h')
PERIOD = struct.Struct('<3H')
HAND_INFO = struct.Struct('<HHBbB')     # hw version, fw version, side, board temp C, status


class PartialReadFilter(logging.Filter):
    """Drops python-can's socketcand "Got incomplete message => waiting for more data": one
    TCP read ending mid-frame, which the client keeps and completes with the next read (no frame
    is lost: test/devices/test_devices_socketcand_fragments.py). At 1333 frames/s it was
    hundreds of log lines a minute. Its other warnings (discarded data) still pass; `suppressed`
    counts what was dropped."""

    MESSAGE = 'Got incomplete message => waiting for more data'

    def __init__(self) -> None:
        super().__init__()
        self.suppressed = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage() == self.MESSAGE:
            self.suppressed += 1
            return False
        return True


PARTIAL_READS = PartialReadFilter()
SOCKETCAND_LOGGER = 'can.interfaces.socketcand.socketcand'


class AllegroError(RuntimeError):
    """The hand did not answer, or the bus failed."""


def wire_id(command: int, device: int = 0) -> int:
    """11-bit CAN id of a command, e.g. SET_TORQUE of finger 1 -> 0x184."""
    return (command << 2) | device


def split_wire_id(arbitration_id: int) -> tuple[int, int]:
    """(command, device) of a CAN id."""
    return arbitration_id >> 2, arbitration_id & 0x3


def torque_to_pwm(tau: np.ndarray, pwm_per_nm: float = PWM_PER_NM_V4) -> np.ndarray:
    """Nm -> int16 PWM, rounded to nearest (0.35 Nm -> 420 on V4) and saturated to int16."""
    pwm = np.rint(np.asarray(tau, dtype=np.float64) * pwm_per_nm)
    return np.clip(pwm, -32768, 32767).astype(np.int16)


def encode_torque(pwm4: np.ndarray) -> bytes:
    return POSE.pack(*(int(v) for v in pwm4))


def decode_int16x4(data: bytes) -> np.ndarray:
    """The 4 int16 fields of a FINGER_POSE or SET_TORQUE payload."""
    return np.array(POSE.unpack(bytes(data)), dtype=np.int16)


def encode_period(position_ms: int, imu_ms: int = 0, temperature_ms: int = 0) -> bytes:
    return PERIOD.pack(position_ms, imu_ms, temperature_ms)


@dataclass(frozen=True)
class HandInfo:
    hardware_version: int
    firmware_version: int
    side: str                   # 'right' | 'left'
    board_temperature_c: int
    servo_on: bool
    over_temperature: bool
    internal_comm_fault: bool

    @property
    def is_v4(self) -> bool:
        return self.hardware_version >> 8 == 4

    def encode(self) -> bytes:
        status = (self.servo_on | self.over_temperature << 1 | self.internal_comm_fault << 2)
        return HAND_INFO.pack(self.hardware_version, self.firmware_version,
                              0 if self.side == 'right' else 1, self.board_temperature_c, status)

    @classmethod
    def decode(cls, data: bytes) -> HandInfo:
        hardware, firmware, side, temperature, status = HAND_INFO.unpack(bytes(data))
        return cls(hardware, firmware, 'left' if side else 'right', temperature,
                   bool(status & 1), bool(status & 2), bool(status & 4))


@dataclass(frozen=True)
class AllegroConfig:
    """``interface``/``channel``/``bus_kwargs`` go to ``can.Bus`` unchanged (pcan, socketcan,
    socketcand, virtual, ...). ``stale_after`` defaults to ~7 missed 3 ms cycles."""

    interface: str = 'pcan'
    channel: str = 'PCAN_USBBUS1'
    bus_kwargs: dict = field(default_factory=lambda: {'bitrate': 1_000_000})
    device_id: int = 0
    position_period_ms: int = 3
    pwm_per_nm: float = PWM_PER_NM_V4
    torque_limits: tuple[float, ...] = tuple(FIRMWARE_TORQUE_LIMITS)
    rtr_requests: bool = True
    reply_timeout: float = 1.0
    stale_after: float = 0.02


@dataclass(frozen=True)
class JointSample:
    """One full FINGER_POSE cycle (all four fingers): positions (16,) float64 rad."""

    positions: np.ndarray
    counts: np.ndarray
    stamp: ArrivalStamp


class AllegroV4Driver(PollingDriver[JointSample]):
    """Torque driver: start-up in the constructor, pose stream via poll()/start(), torques via
    :meth:`set_torques`. ``close()`` (and any fatal error) stops the stream, sends zero torques
    and switches the servos off. Torques are clamped on the host to ``torque_limits``."""

    def __init__(self, config: AllegroConfig, bus: can.BusABC | None = None) -> None:
        super().__init__(config.stale_after, poll_timeout=0.01)
        self.config = config
        self.torque_limits = np.asarray(config.torque_limits, dtype=np.float64)
        if self.torque_limits.shape != (N_JOINTS,) or np.any(self.torque_limits <= 0):
            raise ValueError('torque_limits must be 16 positive values [Nm]')
        if config.interface == 'socketcand':
            logging.getLogger(SOCKETCAND_LOGGER).addFilter(PARTIAL_READS)   # once: same object
        self.bus = bus if bus is not None else can.Bus(interface=config.interface,
                                                       channel=config.channel,
                                                       **config.bus_kwargs)
        self.hand_info: HandInfo | None = None
        self.serial: str | None = None
        self.temperatures_c = np.full(N_JOINTS, np.nan)
        self._counts = np.zeros(N_JOINTS, dtype=np.int16)
        self._fingers_seen = 0
        try:
            self._start_up()
        except BaseException:
            self.close()
            raise

    def _send(self, command: int, data: bytes = b'') -> None:
        self.bus.send(can.Message(arbitration_id=wire_id(command, self.config.device_id),
                                  data=data, is_extended_id=False))

    def _request(self, command: int) -> None:
        if self.config.rtr_requests:
            self.bus.send(can.Message(arbitration_id=wire_id(command, self.config.device_id),
                                      is_remote_frame=True, dlc=0, is_extended_id=False))
        else:
            self._send(command)

    def _start_up(self) -> None:
        self._send(CMD_SYSTEM_OFF)
        self._request(CMD_HAND_INFO)
        self._request(CMD_SERIAL)
        deadline = time.monotonic() + self.config.reply_timeout
        while (self.hand_info is None or self.serial is None) and time.monotonic() < deadline:
            self._receive(0.01)
        if self.hand_info is None or self.serial is None:
            missing = [name for name, value in (('HAND_INFO', self.hand_info),
                                                ('SERIAL', self.serial)) if value is None]
            raise AllegroError(f'hand did not answer {" and ".join(missing)} within '
                               f'{self.config.reply_timeout} s (rtr_requests='
                               f'{self.config.rtr_requests})')
        self._send(CMD_SET_PERIOD, encode_period(self.config.position_period_ms))
        self._send(CMD_SYSTEM_ON)

    def set_torques(self, tau: np.ndarray) -> np.ndarray:
        """Command 16 joint torques [Nm] (Allegro order); returns the PWM values sent."""
        tau = np.asarray(tau, dtype=np.float64)
        if tau.shape != (N_JOINTS,) or not np.all(np.isfinite(tau)):
            raise ValueError(f'need 16 finite torques, got shape {tau.shape}')
        pwm = torque_to_pwm(np.clip(tau, -self.torque_limits, self.torque_limits),
                            self.config.pwm_per_nm)
        for finger in range(N_FINGERS):
            self._send(CMD_SET_TORQUE + finger, encode_torque(pwm[4 * finger:4 * finger + 4]))
        return pwm

    def _receive(self, timeout: float) -> list[JointSample]:
        samples = []
        message = self.bus.recv(timeout)
        while message is not None:
            stamp = ArrivalStamp.now()
            self.diagnostics.note_received(stamp.monotonic)
            sample = self._decode(message, stamp)
            if sample is not None:
                samples.append(sample)
            message = self.bus.recv(0.0)
        return samples

    def _decode(self, message: can.Message, stamp: ArrivalStamp) -> JointSample | None:
        command, device = split_wire_id(message.arbitration_id)
        if message.is_error_frame or message.is_remote_frame or device != self.config.device_id:
            self.diagnostics.add(dropped=1)
            return None
        finger = command & 0x3
        if command & ~0x3 == CMD_FINGER_POSE:
            if message.dlc != POSE.size:
                self.diagnostics.note_malformed(f'FINGER_POSE {finger} with DLC {message.dlc}')
                return None
            return self._pose_frame(finger, decode_int16x4(message.data), stamp)
        if command == CMD_HAND_INFO and message.dlc == HAND_INFO.size:
            self.hand_info = HandInfo.decode(message.data)
        elif command == CMD_SERIAL and message.dlc == 8:
            self.serial = bytes(message.data).decode('ascii', errors='replace')
        elif command & ~0x3 == CMD_TEMPERATURE and message.dlc == 4:
            self.temperatures_c[4 * finger:4 * finger + 4] = list(message.data)
        elif command in (CMD_HAND_INFO, CMD_SERIAL) and message.dlc == 0:
            self.diagnostics.add(dropped=1)       # our own request, relayed by the transport
        elif command in (CMD_HAND_INFO, CMD_SERIAL) or command & ~0x3 == CMD_TEMPERATURE:
            self.diagnostics.note_malformed(f'id 0x{message.arbitration_id:03x} with DLC '
                                            f'{message.dlc}')
        else:
            self.diagnostics.add(dropped=1)
            self.diagnostics.last_error = f'unexpected CAN id 0x{message.arbitration_id:03x}'
        return None

    def _pose_frame(self, finger: int, counts: np.ndarray,
                    stamp: ArrivalStamp) -> JointSample | None:
        bit = 1 << finger
        if self._fingers_seen & bit:
            self.diagnostics.add(gaps=1)      # a frame of the previous cycle never arrived
            self._fingers_seen = 0
        self._fingers_seen |= bit
        self._counts[4 * finger:4 * finger + 4] = counts
        if self._fingers_seen != 0xF:
            return None
        self._fingers_seen = 0
        counts16 = self._counts.copy()
        return JointSample(counts16.astype(np.float64) * RAD_PER_COUNT, counts16, stamp)

    def _make_safe(self) -> None:
        """Zero torques and servo off, best effort (the bus may be what failed)."""
        for step in (lambda: self.set_torques(np.zeros(N_JOINTS)),
                     lambda: self._send(CMD_SYSTEM_OFF)):
            try:
                step()
            except (can.CanError, OSError) as error:
                self.diagnostics.last_error = f'safe stop failed: {error!r}'

    def _on_fatal(self, error: BaseException) -> None:
        self._make_safe()

    def _shutdown(self) -> None:
        try:
            self._send(CMD_SET_PERIOD, encode_period(0))
        except (can.CanError, OSError) as error:
            self.diagnostics.last_error = f'stop stream failed: {error!r}'
        self._make_safe()
        self.bus.shutdown()
