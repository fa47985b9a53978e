"""Allegro Hand V4 torque driver over CAN (python-can, any interface): start-up and
identification, the joint stream, torques, and a safe stop. Its frames are in allegro_codec.py,
the socketcand link in socketcand_link.py.

HAND_INFO/SERIAL are requested with remote (RTR) frames on a real bus; transports that cannot
carry RTR (python-can's socketcand client) need ``rtr_requests=False``, which sends zero-length
data frames instead. Torques as int16 PWM = tau[Nm] * ``pwm_per_nm`` (1200 on V4, 800 on older
8 V hands).
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field

import can
import numpy as np

from tacforce_ros.devices.allegro_codec import (CMD_FINGER_POSE, CMD_HAND_INFO, CMD_SERIAL,
                                                CMD_SET_PERIOD, CMD_SET_TORQUE, CMD_SYSTEM_OFF,
                                                CMD_SYSTEM_ON, CMD_TEMPERATURE, HAND_INFO,
                                                N_FINGERS, N_JOINTS, POSE, PWM_PER_NM_V4,
                                                RAD_PER_COUNT, AllegroError, HandInfo,
                                                decode_int16x4, encode_period, encode_torque,
                                                split_wire_id, torque_to_pwm, wire_id)
from tacforce_ros.devices.diagnostics import ArrivalStamp
from tacforce_ros.devices.polling import LinkLost, PollingDriver
from tacforce_ros.devices.socketcand_link import (SOCKETCAND_LOG, SOCKETCAND_LOGGER, open_bus,
                                                 peer_closed, socketcand_socket)
from tacforce_ros.rig import TORQUE_LIMITS


@dataclass(frozen=True)
class AllegroConfig:
    """``interface``/``channel``/``bus_kwargs`` go to ``can.Bus`` unchanged (pcan, socketcan,
    socketcand, virtual, ...). ``stale_after`` defaults to ~7 missed 3 ms cycles.

    A silent hand (no complete FINGER_POSE cycle while the link is up): after
    ``silent_warn_after`` s a warning, and the stream is requested again (SET_PERIOD) every
    ``silent_warn_after`` s; after ``silent_timeout`` s zero torque and servos off, and torque
    commands are refused from then on (the servos stay off when the stream returns). A check
    that comes more than ``silent_warn_after``/2 after the previous one (the host did not run
    the driver) is counted in ``diagnostics.late_polls`` and defers any verdict by that long
    again, so that a hand stalled with the driver (an emulator) is heard before it is blamed.
    """

    interface: str = 'pcan'
    channel: str = 'PCAN_USBBUS1'
    bus_kwargs: dict = field(default_factory=lambda: {'bitrate': 1_000_000})
    device_id: int = 0
    position_period_ms: int = 3
    pwm_per_nm: float = PWM_PER_NM_V4
    torque_limits: tuple[float, ...] = tuple(TORQUE_LIMITS)
    rtr_requests: bool = True
    reply_timeout: float = 1.0
    stale_after: float = 0.02
    silent_warn_after: float = 0.5
    silent_timeout: float = 2.0

    def __post_init__(self) -> None:
        if not 0 < self.silent_warn_after < self.silent_timeout:
            raise ValueError('need 0 < silent_warn_after < silent_timeout, got '
                             f'{self.silent_warn_after} and {self.silent_timeout}')


# The joint stream at the default period (one FINGER_POSE cycle every 3 ms): a control loop
# faster than it has no new joint state to act on.
MAX_JOINT_RATE_HZ = 1000.0 / AllegroConfig.position_period_ms


@dataclass(frozen=True)
class JointSample:
    """One full FINGER_POSE cycle (all four fingers): positions (16,) float64 rad."""

    positions: np.ndarray
    counts: np.ndarray
    stamp: ArrivalStamp


class AllegroV4Driver(PollingDriver[JointSample]):
    """Torque driver: start-up in the constructor (``servos_on`` False: identified only, until
    :meth:`servos_on`), pose stream via poll()/start(), torques via
    :meth:`set_torques`. ``close()`` (and any fatal error, a lost link included) stops the
    stream, sends zero torques and switches the servos off. Torques are clamped on the host to
    ``torque_limits``. ``safe_stop`` says why the driver made the hand safe by itself (a silent
    hand), '' while it has not."""

    def __init__(self, config: AllegroConfig, bus: can.BusABC | None = None, *,
                 servos_on: bool = True) -> None:
        super().__init__(config.stale_after, poll_timeout=0.01)
        self.config = config
        self.torque_limits = np.asarray(config.torque_limits, dtype=np.float64)
        if self.torque_limits.shape != (N_JOINTS,) or np.any(self.torque_limits <= 0):
            raise ValueError('torque_limits must be 16 positive values [Nm]')
        if config.interface == 'socketcand':
            logging.getLogger(SOCKETCAND_LOGGER).addFilter(SOCKETCAND_LOG)   # once: same object
        self.bus = bus if bus is not None else open_bus(config)
        self._socket = socketcand_socket(self.bus)
        # Frames go out from the polling thread (stream requests, safe stops) and the caller's
        # (torques, servos on/off): one at a time, and the stream state with them.
        self._lock = threading.RLock()
        self.safe_stop = ''
        self._send_failure = ''                   # a send timed out: the peer reads nothing
        self._streaming = False                   # the stream was asked for (start-up done)
        self._last_cycle: float | None = None     # monotonic time of the last complete cycle
        self._last_watch: float | None = None     # monotonic time of the last silence check
        self._judge_after = 0.0                   # no silence verdict before (after a stall)
        self._silent = False
        self._last_request = 0.0
        self.hand_info: HandInfo | None = None
        self.serial: str | None = None
        self.temperatures_c = np.full(N_JOINTS, np.nan)
        self._counts = np.zeros(N_JOINTS, dtype=np.int16)
        self._fingers_seen = 0
        try:
            self._identify()
            if servos_on:
                self.servos_on()
        except BaseException:
            self.close()
            raise

    def _send(self, command: int, data: bytes = b'') -> None:
        if self._send_failure:          # each frame would wait out the timeout again
            raise LinkLost(self._send_failure)
        try:
            with self._lock:
                self.bus.send(can.Message(arbitration_id=wire_id(command, self.config.device_id),
                                          data=data, is_extended_id=False))
        except (can.CanError, OSError) as error:
            message = f'link lost: sending to the hand failed: {error!r}'
            if isinstance(error, (BlockingIOError, TimeoutError)):    # the send timed out
                self._send_failure = message
            raise LinkLost(message) from error

    def _request(self, command: int) -> None:
        if self.config.rtr_requests:
            with self._lock:
                self.bus.send(can.Message(arbitration_id=wire_id(command, self.config.device_id),
                                          is_remote_frame=True, dlc=0, is_extended_id=False))
        else:
            self._send(command)

    def _identify(self) -> None:
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

    def servos_on(self) -> None:
        """Start the joint stream and switch the servos on (the end of the hand's start-up; a
        managed driver's activate). A hand the silence policy made safe starts afresh."""
        with self._lock:
            self._last_cycle = self._last_watch = None
            self._silent = False
            self._judge_after = 0.0
            self.safe_stop = ''
            self._send(CMD_SET_PERIOD, encode_period(self.config.position_period_ms))
            self._send(CMD_SYSTEM_ON)
            self._streaming = True

    def servos_off(self) -> None:
        """Stop the joint stream, zero torque, servos off, the link kept open (a managed
        driver's deactivate); best effort, failures in ``diagnostics.last_error``."""
        with self._lock:
            self._streaming = False
            try:
                self._send(CMD_SET_PERIOD, encode_period(0))
            except LinkLost as error:
                self.diagnostics.last_error = f'stop stream failed: {error}'
            self._make_safe()

    def set_torques(self, tau: np.ndarray) -> np.ndarray:
        """Command 16 joint torques [Nm] (Allegro order); returns the PWM values sent.
        AllegroError once the driver made the hand safe by itself (``safe_stop``)."""
        if self.safe_stop:
            raise AllegroError(f'torque refused: {self.safe_stop}')
        return self._send_torques(tau)

    def _send_torques(self, tau: np.ndarray) -> np.ndarray:
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
        try:
            message = self.bus.recv(timeout)
            if message is None and self._socket is not None and peer_closed(self._socket):
                raise LinkLost('link lost: the socketcand server closed the connection')
            while message is not None:
                stamp = ArrivalStamp.now()
                self.diagnostics.note_received(stamp.monotonic)
                sample = self._decode(message, stamp)
                if sample is not None:
                    samples.append(sample)
                message = self.bus.recv(0.0)
            with self._lock:
                if self._streaming:
                    self._watch_stream(bool(samples))
        except LinkLost:
            raise
        except (can.CanError, OSError) as error:
            raise LinkLost(f'link lost: {error}') from error
        return samples

    def _watch_stream(self, cycle_completed: bool) -> None:
        """The silent-hand policy (see AllegroConfig), checked on every poll."""
        now = time.monotonic()
        grace = self.config.silent_warn_after / 2
        if self._last_watch is not None and now - self._last_watch > grace:
            # This thread was not run (an overloaded host stalls every thread, an emulated hand's
            # too): the hand gets that long again, with the driver awake, to be heard.
            self._judge_after = now + grace
            self.diagnostics.add(late_polls=1)
        self._last_watch = now
        if cycle_completed or self._last_cycle is None:
            if self._silent:
                self._silent = False
                self._event(logging.INFO, f'joint stream back after {now - self._last_cycle:.2f} s'
                            + ('; servos stay off' if self.safe_stop else ''))
            self._last_cycle = now
            return
        silence = now - self._last_cycle
        if silence < self.config.silent_warn_after or now < self._judge_after:
            return
        if not self._silent:
            self._silent = True
            self._event(logging.WARNING, f'hand silent: no joint data for {silence:.2f} s with '
                        'the link up; asking for the stream again every '
                        f'{self.config.silent_warn_after:g} s, zero torque and servos off after '
                        f'{self.config.silent_timeout:g} s')
        if now - self._last_request >= self.config.silent_warn_after:
            self._last_request = now
            self._send(CMD_SET_PERIOD, encode_period(self.config.position_period_ms))
        if silence >= self.config.silent_timeout and not self.safe_stop:
            # Refuse torque commands first: a controller thread may be sending one right now.
            self.safe_stop = (f'the hand sent no joint data for {silence:.2f} s: zero torque '
                              'sent and servos switched off')
            self._make_safe()
            self._event(logging.ERROR, self.safe_stop)

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
        for step in (lambda: self._send_torques(np.zeros(N_JOINTS)),
                     lambda: self._send(CMD_SYSTEM_OFF)):
            try:
                step()
            except LinkLost as error:
                self.diagnostics.last_error = f'safe stop failed: {error}'

    def _on_fatal(self, error: BaseException) -> None:
        self._make_safe()

    def _before_stop(self) -> None:
        self.servos_off()

    def _shutdown(self) -> None:
        self.bus.shutdown()
