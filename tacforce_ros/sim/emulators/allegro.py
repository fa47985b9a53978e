"""An Allegro Hand V4 on an emulated CAN bus (socketcand server on 127.0.0.1).

It answers as the firmware does: HAND_INFO/SERIAL requests (RTR on a real bus; zero-length data
frames here, since socketcand carries no RTR), SET_PERIOD starts or stops the FINGER_POSE
stream, SYSTEM_ON/OFF switch the servos, SET_TORQUE frames are clamped to the firmware limits and
passed to ``torque_sink`` while the servos are on. When torque frames stop coming (a driver
killed, a client gone) the last torque stays applied: what the V4 firmware does then is not
documented (docs/PROTOCOLS.md), and keeping it is the worst case for the hand's surroundings.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

import can
import numpy as np

from tacforce_ros.devices.allegro_codec import (CMD_FINGER_POSE, CMD_HAND_INFO, CMD_SERIAL,
                                                CMD_SET_PERIOD, CMD_SET_TORQUE, CMD_SYSTEM_OFF,
                                                CMD_SYSTEM_ON, N_FINGERS, N_JOINTS, PERIOD,
                                                PWM_PER_NM_V4, RAD_PER_COUNT, HandInfo,
                                                decode_int16x4, encode_torque, split_wire_id,
                                                wire_id)
from tacforce_ros.rig import TORQUE_LIMITS
from tacforce_ros.sim.emulators.base import LOOPBACK, Pacer
from tacforce_ros.sim.emulators.socketcand import SocketcandServer

JointSource = Callable[[], np.ndarray]       # -> q (16,) rad, Allegro joint order
TorqueSink = Callable[[np.ndarray], None]    # <- tau (16,) Nm after every SET_TORQUE frame


# A right V4 hand at 30 C, servos off, no faults (sim_world makes it the scene hand's side).
V4_HAND_INFO = HandInfo(0x0400, 0x0100, 'right', 30, False, False, False)


class AllegroEmulator:
    """The hand behind a socketcand server. ``sent_log`` keeps (cycle, monotonic time of the
    cycle's first FINGER_POSE send); fault hooks: :meth:`inject`, :meth:`pause_stream`."""

    def __init__(self, joint_source: JointSource, torque_sink: TorqueSink,
                 host: str = LOOPBACK, port: int = 0, channel: str = 'can0',
                 hand_info: HandInfo = V4_HAND_INFO,
                 serial: str = 'SAH040X1', pwm_per_nm: float = PWM_PER_NM_V4,
                 device_id: int = 0, log_length: int = 100_000) -> None:
        if len(serial.encode('ascii')) != 8:
            raise ValueError('the SERIAL reply carries exactly 8 ASCII characters')
        self.joint_source = joint_source
        self.torque_sink = torque_sink
        self.hand_info = hand_info
        self.serial = serial
        self.pwm_per_nm = pwm_per_nm
        self.device_id = device_id
        self.servo_on = False
        self.torques = np.zeros(N_JOINTS, dtype=np.float64)
        self.period_ms = 0
        self.paused = False
        self.sent_log: deque[tuple[int, float]] = deque(maxlen=log_length)
        self._period_changed = threading.Event()
        self._stop = threading.Event()
        self.server = SocketcandServer(self._on_frame, host, port, channel)
        self.diagnostics = self.server.diagnostics
        self._thread = threading.Thread(target=self._stream, daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        return self.server.address

    def bus_kwargs(self) -> dict:
        """Keyword arguments for ``can.Bus`` reaching this hand through python-can."""
        host, port = self.address
        return {'interface': 'socketcand', 'channel': self.server.channel, 'host': host,
                'port': port, 'tcp_tune': True}

    def _message(self, command: int, data: bytes) -> can.Message:
        return can.Message(arbitration_id=wire_id(command, self.device_id), data=data,
                           is_extended_id=False, timestamp=time.time())

    def _on_frame(self, message: can.Message) -> None:
        command, device = split_wire_id(message.arbitration_id)
        if device != self.device_id:
            return
        if command == CMD_SYSTEM_ON and message.dlc == 0:
            self.servo_on = True
        elif command == CMD_SYSTEM_OFF and message.dlc == 0:
            self.servo_on = False
            self._apply_torques(np.zeros(N_JOINTS))
        elif command == CMD_HAND_INFO and message.dlc == 0:
            self.server.broadcast([self._message(CMD_HAND_INFO, self.hand_info.encode())])
        elif command == CMD_SERIAL and message.dlc == 0:
            self.server.broadcast([self._message(CMD_SERIAL, self.serial.encode('ascii'))])
        elif command == CMD_SET_PERIOD and message.dlc == PERIOD.size:
            self.period_ms = PERIOD.unpack(bytes(message.data))[0]
            self._period_changed.set()
        elif command & ~0x3 == CMD_SET_TORQUE and message.dlc == 8:
            finger = command & 0x3
            tau = self.torques.copy()
            tau[4 * finger:4 * finger + 4] = decode_int16x4(message.data) / self.pwm_per_nm
            self._apply_torques(np.clip(tau, -TORQUE_LIMITS, TORQUE_LIMITS))
        else:
            self.diagnostics.note_malformed(
                f'hand ignored id 0x{message.arbitration_id:03x} DLC {message.dlc}')

    def _apply_torques(self, tau: np.ndarray) -> None:
        self.torques = tau if self.servo_on else np.zeros(N_JOINTS)
        self.torque_sink(self.torques.copy())

    def _pose_frames(self) -> list[can.Message]:
        q = np.asarray(self.joint_source(), dtype=np.float64)
        counts = np.clip(np.rint(q / RAD_PER_COUNT), -32768, 32767).astype(np.int16)
        return [self._message(CMD_FINGER_POSE + f, encode_torque(counts[4 * f:4 * f + 4]))
                for f in range(N_FINGERS)]

    def _stream(self) -> None:
        cycle = 0
        while not self._stop.is_set():
            self._period_changed.clear()
            if self.period_ms == 0:
                self._period_changed.wait(0.05)
                continue
            pacer = Pacer(1000.0 / self.period_ms)
            while not self._period_changed.is_set() and pacer.wait(self._stop):
                if self.paused:
                    continue
                frames = self._pose_frames()
                self.sent_log.append((cycle, time.monotonic()))
                self.server.broadcast(frames)
                cycle += 1

    # --- fault injection -------------------------------------------------------------------
    def inject(self, arbitration_id: int, data: bytes) -> None:
        """Put an arbitrary frame on the bus (wrong DLC, unknown id ...)."""
        self.server.broadcast([can.Message(arbitration_id=arbitration_id, data=data,
                                           is_extended_id=False, timestamp=time.time())])

    def pause_stream(self, paused: bool = True) -> None:
        """Stop (or resume) sending FINGER_POSE frames without being told to."""
        self.paused = paused

    def forget_stream(self) -> None:
        """Lose the stream period, as a board that reset itself does: silent until a host sends
        SET_PERIOD again."""
        self.period_ms = 0
        self._period_changed.set()

    def close(self) -> None:
        self._stop.set()
        self._period_changed.set()
        self._thread.join(timeout=2.0)
        self.server.close()

    def __enter__(self) -> AllegroEmulator:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def main(argv: list[str] | None = None) -> None:
    """Serve a hand holding a fixed pose until stdin closes (or ``--duration``), then print a
    JSON summary: used to reach the emulator from another process."""
    import argparse
    import json
    import sys

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument('--port', type=int, default=0, help='TCP port on 127.0.0.1 (0: any)')
    parser.add_argument('--pose', type=float, nargs=N_JOINTS, default=[0.0] * N_JOINTS,
                        help='the 16 joint angles [rad] the hand reports')
    parser.add_argument('--duration', type=float, default=60.0, help='upper bound [s]')
    args = parser.parse_args(argv)
    received: list[np.ndarray] = []
    pose = np.asarray(args.pose, dtype=np.float64)
    with AllegroEmulator(lambda: pose, received.append, port=args.port) as emulator:
        print(json.dumps({'port': emulator.address[1]}), flush=True)
        done = threading.Event()
        threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
        done.wait(args.duration)
        # Summarise only after the clients hung up: all they sent has then been handled.
        deadline = time.monotonic() + 2.0
        while emulator.server.client_count and time.monotonic() < deadline:
            time.sleep(0.01)
        summary = {'servo_on': emulator.servo_on, 'period_ms': emulator.period_ms,
                   'torque_frames': len(received),
                   'max_torques': np.max(np.abs(received), axis=0).tolist() if received else [],
                   'last_torques': received[-1].tolist() if received else [],
                   'malformed': emulator.diagnostics.malformed}
    print(json.dumps(summary), flush=True)


if __name__ == '__main__':
    main()
