"""Write already-serialised (CDR) messages into a calibration bag.

A node subscribing with raw=True receives the CDR bytes rosbag2 stores; writing them directly
avoids decoding and copying every field. `CalibrationBagWriter` (bagio.py, the lead's)
serialises rosbags messages itself; this adds the bytes path on top of it (it reads the
writer's private state). TODO(lead): move `write_serialized` and `flush_if_due` into
CalibrationBagWriter (and have `write` call them), then delete this module.
"""
from __future__ import annotations

import time

from tacforce_ros.bagio import BagError, CalibrationBagWriter


class SerializedBagWriter(CalibrationBagWriter):
    """CalibrationBagWriter that also takes CDR bytes; same splits and crash tolerance."""

    def write_serialized(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """Write one CDR-serialised message; closes the split when it is old enough."""
        if self._writer is None:
            raise BagError(f'bag {self.path} is closed')
        connection = self._connections.get(topic)
        if connection is None:
            raise BagError(f'topic {topic} is not part of this bag ({sorted(self.topics)})')
        self._writer.write(connection, int(stamp_ns), bytes(data))
        self.flush_if_due()

    def flush_if_due(self) -> None:
        """Close the split once it is `split_seconds` old (call it from a timer too, so a quiet
        stream still reaches the disk)."""
        if time.monotonic() - self._split_started >= self.split_seconds:
            self.flush()
