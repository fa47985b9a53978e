"""Stamps from a device's own timestamps, so that samples are stamped when the device took them
rather than when the host got round to reading them: the spacing of the device's samples is
kept whatever the transport and the host's scheduling add. Plain Python, no ROS.

Two cases. The device's clock IS the host clock (`same_clock`: a server process on this host
stamping with its system time, which is ROS time; or a simulator's device emulator stamping with
simulated time, which the host reads from /clock): its timestamps are used as they are. The
device has a clock of its own (another computer, a free-running counter): its timestamps are
mapped onto the host clock with the passive minimum-delay estimate of E. Olson, "A passive
solution to the sensor synchronization problem", IROS 2010. Every sample bounds the offset
from above, arrival - device time = offset + transport delay (delay >= 0), so the smallest bound
seen is the best estimate, an older bound being loosened by the largest skew the two clocks may
have (`max_skew`, s/s) times the device time elapsed since. That estimate needs arrivals read on
a clock that never runs behind the device's, which a host clock fed by /clock does not give (it
lags simulated time by up to the delivery of a /clock message): hence the first case.

Either way: a device time that does not advance (the device repeated a sample) gives no stamp;
one that goes backwards (the device's clock was set back) restarts the estimate; a stamp that
would not be later than the previous one (mapped: the estimate fell by more than the sample
interval, e.g. after first samples that came late) is moved to 1 ns after it. All are counted.
"""
from __future__ import annotations

from dataclasses import dataclass

# An estimate: two quartz clocks specified to +-50 ppm each (common for crystal oscillators).
DEFAULT_MAX_SKEW = 1e-4


@dataclass
class DeviceClockCounts:
    repeated: int = 0       # samples whose device time did not advance (no stamp)
    resets: int = 0         # device clock went backwards: the estimate restarted
    moved: int = 0          # stamps moved to keep the stream strictly increasing


class DeviceClock:
    """Device times (integer ns on the device's clock) to host-clock stamps (ns)."""

    def __init__(self, same_clock: bool, max_skew: float = DEFAULT_MAX_SKEW) -> None:
        if not 0.0 <= max_skew < 0.01:
            raise ValueError(f'max_skew: {max_skew} s/s must be in [0, 0.01)')
        self.same_clock = same_clock
        self.max_skew = max_skew
        self.counts = DeviceClockCounts()
        self._bound: tuple[int, int] | None = None   # (offset ns, device ns it was seen at)
        self._last_device: int | None = None
        self._last_stamp: int | None = None

    def offset_ns(self, device_ns: int) -> int | None:
        """Host minus device clock at device time `device_ns` (None: no sample yet)."""
        if self.same_clock:
            return 0
        if self._bound is None:
            return None
        offset, seen_at = self._bound
        return offset + int(self.max_skew * max(0, device_ns - seen_at))

    def stamp(self, device_ns: int, arrival_ns: int) -> int | None:
        """The host-clock stamp of a sample taken at `device_ns` and read at `arrival_ns`, or
        None when the device time did not advance (a repeated sample)."""
        device_ns, arrival_ns = int(device_ns), int(arrival_ns)
        if self._last_device is not None:
            if device_ns == self._last_device:
                self.counts.repeated += 1
                return None
            if device_ns < self._last_device:
                self.counts.resets += 1
                self._bound = None
        self._last_device = device_ns
        offset = self.offset_ns(device_ns)
        bound = arrival_ns - device_ns
        if not self.same_clock and (offset is None or bound <= offset):
            self._bound, offset = (bound, device_ns), bound
        stamp = device_ns + offset
        if self._last_stamp is not None and stamp <= self._last_stamp:
            stamp = self._last_stamp + 1
            self.counts.moved += 1
        self._last_stamp = stamp
        return stamp
