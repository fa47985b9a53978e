"""Serialized fast path of the estimator: its hot messages written and read as CDR bytes.

The estimator takes /tactile/raw as serialized bytes and publishes its 18 wrenches and the
estimate array as messages laid out once, skipping rclpy's field-by-field Python <-> C
conversion: `bench_messages` measures both ways per tactile frame (JSON + table; README,
Measured results). The layout is the plain little-endian CDR that rmw serialises ROS 2 messages
to: a 4-byte encapsulation header, then every field aligned to its own size (8 for float64)
counted from the end of that header; a string is a uint32 length (NUL included), the bytes and a
NUL; a sequence a uint32 count and the elements.

It mirrors these message definitions, and must change with them:
    msg/TactileHand.msg, msg/TactileArray.msg      (read: TactileHandDecoder)
    msg/ForceEstimateArray.msg, msg/ForceEstimate.msg   (written: serialized_estimates)
    geometry_msgs/WrenchStamped, geometry_msgs/Wrench, geometry_msgs/Vector3,
    std_msgs/Header, builtin_interfaces/Time       (written: serialized_wrenches; read:
                                                    header_stamp_ns)
test/nodes/test_nodes_estimator_serialized.py compares every byte with
rclpy.serialization.serialize_message of the generated classes, so it fails when one of these
definitions changes and this module does not.
"""
from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

from tacforce_ros.hand.description import HandDescription

_CDR_LE = b'\x00\x01\x00\x00'       # encapsulation: plain CDR, little-endian
_HEAD = len(_CDR_LE)
_U32 = struct.Struct('<I')
_STAMP = struct.Struct('<iI')


def _aligned(pos: int, size: int) -> int:
    return pos + (-(pos - _HEAD) % size)


class _CdrWriter:
    """One serialized message built field by field; `slots` remembers where the numbers that
    change per message went (offset of each, by slot name)."""

    def __init__(self) -> None:
        self.buf = bytearray(_CDR_LE)
        self.slots: dict[str, list[int]] = {}

    def scalars(self, code: str, values: Sequence, slot: str | None = None) -> None:
        """Little-endian values of one struct type code, e.g. ('d', force)."""
        size = struct.calcsize(code)
        self.buf += bytes(_aligned(len(self.buf), size) - len(self.buf))
        if slot is not None:
            self.slots.setdefault(slot, []).extend(
                range(len(self.buf), len(self.buf) + size * len(values), size))
        self.buf += struct.pack(f'<{len(values)}{code}', *values)

    def string(self, text: str) -> None:
        data = text.encode() + b'\0'
        self.scalars('I', (len(data),))
        self.buf += data

    def header(self, frame_id: str) -> None:
        """std_msgs/Header; its stamp goes to the 'stamp' slot (sec offset)."""
        self.scalars('i', (0,), 'stamp')
        self.scalars('I', (0,))
        self.string(frame_id)


_SLOT_DTYPES = {'d': np.float64, 'f': np.float32, '?': np.bool_}


class SerializedMessages:
    """Serialized messages laid out once; per tick only their stamps and numbers are written.

    Each message starts 8-byte aligned in one shared buffer, so one numpy assignment writes a
    slot (e.g. every force) of all messages at once; `message(k)` copies message k out as the
    bytes a publisher takes.
    """

    def __init__(self, writers: Sequence[_CdrWriter], slot_codes: dict[str, str]) -> None:
        starts, buffer = [], bytearray()
        for writer in writers:
            buffer += bytes(-len(buffer) % 8)
            starts.append(len(buffer))
            buffer += writer.buf
        buffer += bytes(-len(buffer) % 8)
        self._buffer, self._memory = buffer, memoryview(buffer)
        self._spans = [(s, s + len(w.buf)) for s, w in zip(starts, writers)]
        self._u32 = np.frombuffer(buffer, np.uint32)
        self._i32 = np.frombuffer(buffer, np.int32)

        def absolute(name: str) -> np.ndarray:
            return np.concatenate([np.asarray(w.slots.get(name, []), dtype=np.intp) + s
                                   for s, w in zip(starts, writers)])

        stamps = absolute('stamp') // 4
        self._sec, self._nanosec = stamps, stamps + 1
        self._slots = {}
        for name, code in slot_codes.items():
            dtype = np.dtype(_SLOT_DTYPES[code])
            at = absolute(name)
            base = int(at[0]) % dtype.itemsize if at.size else 0   # 8-byte values sit at 4 mod 8
            view = np.frombuffer(buffer, dtype, offset=base,
                                 count=(len(buffer) - base) // dtype.itemsize)
            self._slots[name] = (view, (at - base) // dtype.itemsize)

    def __len__(self) -> int:
        return len(self._spans)

    def set_stamp(self, ns: int) -> None:
        sec, nanosec = divmod(int(ns), 1_000_000_000)
        self._i32[self._sec] = sec
        self._u32[self._nanosec] = nanosec

    def set(self, slot: str, values: np.ndarray | float) -> None:
        """Every value of a slot, in message then field order (e.g. forces (k, 3))."""
        view, index = self._slots[slot]
        view[index] = np.ravel(values)

    def message(self, k: int) -> bytes:
        start, end = self._spans[k]
        return bytes(self._memory[start:end])


def serialized_wrenches(frame_ids: Sequence[str]) -> SerializedMessages:
    """One geometry_msgs/WrenchStamped per frame id (zero torque); slots: stamp, 'force'."""
    writers = []
    for frame_id in frame_ids:
        writer = _CdrWriter()
        writer.header(frame_id)
        writer.scalars('d', (0.0,) * 3, 'force')
        writer.scalars('d', (0.0,) * 3)
        writers.append(writer)
    return SerializedMessages(writers, {'force': 'd'})


def serialized_estimates(hand_frame: str, names: Sequence[str], frame_ids: Sequence[str],
                         kinds: Sequence[str], statuses: Sequence[str]) -> SerializedMessages:
    """One tacforce_msgs/ForceEstimateArray with these per-array strings (the layout depends on
    them); slots: stamp (all headers), 'force' (k, 3), 'valid' (k,), 'ood_score' (k,)."""
    writer = _CdrWriter()
    writer.header(hand_frame)
    writer.scalars('I', (len(names),))
    for name, frame_id, kind, status in zip(names, frame_ids, kinds, statuses, strict=True):
        writer.header(frame_id)
        writer.string(name)
        writer.string(kind)
        writer.scalars('d', (0.0,) * 3, 'force')
        writer.scalars('?', (False,), 'valid')
        writer.string(status)
        writer.scalars('f', (0.0,), 'ood_score')
    return SerializedMessages([writer], {'force': 'd', 'valid': '?', 'ood_score': 'f'})


class TactileHandDecoder:
    """Serialized tacforce_msgs/TactileHand -> (stamp ns, (n_taxels, 3) uint16 counts in XELA
    flat order).

    The first frame's layout is learnt by walking it; later frames with the same layout (same
    length and the same counts, string lengths and strings: every byte but stamps, times and
    readings) are read by one precomputed gather. Anything else is walked again, so a frame
    that does not match the hand raises ValueError naming the array and what is wrong.
    """

    def __init__(self, hand: HandDescription) -> None:
        self.hand = hand
        self._length = -1
        self._fixed_at = np.zeros(0, np.intp)
        self._fixed = np.zeros(0, np.uint8)
        self._counts_at = np.zeros((hand.n_taxels, 3), np.intp)

    def decode(self, raw: bytes) -> tuple[int, np.ndarray]:
        if len(raw) != self._length or not np.array_equal(
                np.frombuffer(raw, np.uint8)[self._fixed_at], self._fixed):
            self._learn(raw)
        sec, nanosec = _STAMP.unpack_from(raw, _HEAD)
        counts = np.frombuffer(raw, np.uint16, count=len(raw) // 2)[self._counts_at]
        return sec * 1_000_000_000 + nanosec, counts

    def _learn(self, raw: bytes) -> None:
        try:
            self._walk(raw)
        except struct.error:
            raise ValueError(f'truncated TactileHand ({len(raw)} bytes)') from None

    def _walk(self, raw: bytes) -> None:
        fixed = [0, 1]      # byte offsets of the encapsulation, counts, lengths and strings
        counts_at = np.empty_like(self._counts_at)

        def u32(pos: int) -> tuple[int, int]:
            pos = _aligned(pos, 4)
            fixed.extend(range(pos, pos + 4))
            return _U32.unpack_from(raw, pos)[0], pos + 4

        def string(pos: int) -> tuple[str, int]:
            size, pos = u32(pos)
            if size < 1 or pos + size > len(raw) or raw[pos + size - 1] != 0:
                raise ValueError(f'malformed string at byte {pos}')
            fixed.extend(range(pos, pos + size))
            return raw[pos:pos + size - 1].decode(errors='replace'), pos + size

        if raw[:2] != _CDR_LE[:2]:
            raise ValueError(f'not little-endian CDR (encapsulation {raw[:2].hex()})')
        _, pos = string(_HEAD + 8)                         # header: stamp, frame_id
        pos = _aligned(pos, 8) + 8 + 4                      # server_time, server_sequence
        n_arrays, pos = u32(pos)
        if n_arrays != len(self.hand.arrays):
            raise ValueError(f'{n_arrays} arrays, the hand has {len(self.hand.arrays)}')
        for spec in self.hand.arrays:
            _, pos = string(_aligned(pos, 4) + 8)           # header: stamp, frame_id
            name, pos = string(pos)
            if name != spec.name:
                raise ValueError(f'array {name!r} where the hand has {spec.name!r}')
            sizes = []
            for axis in range(3):
                size, pos = u32(pos)
                sizes.append(size)
                if size == spec.n_taxels:
                    counts_at[spec.flat_indices, axis] = pos // 2 + np.arange(size)
                pos += 2 * size
            if sizes != [spec.n_taxels] * 3:
                raise ValueError(f'{spec.name}: {sizes} values in x, y, z, expected '
                                 f'{spec.n_taxels} each')
            size, pos = u32(pos)                            # temperatures (float32)
            pos += 4 * size
        if not pos <= len(raw) < pos + 4:                   # rmw may pad the end to 4 bytes
            raise ValueError(f'{len(raw)} bytes where the layout ends at {pos}')
        self._length = len(raw)
        self._fixed_at = np.asarray(fixed, dtype=np.intp)
        self._fixed = np.frombuffer(raw, np.uint8)[self._fixed_at]
        self._counts_at = counts_at


def header_stamp_ns(raw: bytes) -> int:
    """The header stamp of a serialized message whose first field is a std_msgs/Header
    (WrenchStamped, ControllerState, ...), read without deserializing the rest."""
    if raw[:2] != _CDR_LE[:2] or len(raw) < _HEAD + _STAMP.size:
        raise ValueError(f'not a little-endian CDR message with a header ({raw[:4].hex()}, '
                         f'{len(raw)} bytes)')
    sec, nanosec = _STAMP.unpack_from(raw, _HEAD)
    return sec * 1_000_000_000 + nanosec
