"""Allegro Hand V4 CAN frames: command ids, payload codecs and units.

Wire facts (docs/PROTOCOLS.md, Allegro V4 CAN, from simlabrobotics/allegro_hand_ros_v4 and
Wonik's ROS 2 SDK): standard ids ``(command << 2) | device``, little-endian payloads, positions
in encoder counts of 333.3/65536 degrees, torques as int16 PWM = tau[Nm] * 1200 on V4 (800 on
older 8 V hands). The TEMPERATURE frame layout is uncertain.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np



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

POSE = struct.Struct('<4h')
PERIOD = struct.Struct('<3H')
HAND_INFO = struct.Struct('<HHBbB')     # hw version, fw version, side, board temp C, status


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
