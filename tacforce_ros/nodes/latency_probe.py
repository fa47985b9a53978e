"""The probe of bench_ros (benchmarks/bench_ros.py): a node that feeds the estimator node frames and
times what comes back, and watches the controller's tick stamps. How and why it measures as it
does is in that tool's description."""
from __future__ import annotations

import os
import struct
import time
from pathlib import Path

import numpy as np
import rclpy
from geometry_msgs.msg import WrenchStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from tacforce_msgs.msg import ControllerState, ForceEstimateArray, TactileHand

from tacforce_ros.nodes.qos import publisher_qos
from tacforce_ros.nodes.messages import tactile_hand
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.topics import (TOPIC_CONTROLLER_STATE, TOPIC_ESTIMATES, TOPIC_TACTILE,
                                 array_wrench_topic)

WARM_UP_TIMEOUT_S = 60.0
# Every serialized message starts with a 4-byte encapsulation header and then std_msgs/Header,
# whose stamp (int32 sec, uint32 nanosec) comes first.
_STAMP = struct.Struct('<iI')
_STAMP_AT = 4


def _stamp_of(raw: bytes) -> int:
    sec, nanosec = _STAMP.unpack_from(raw, _STAMP_AT)
    return sec * 1_000_000_000 + nanosec


def _percentiles(values_ms) -> dict[str, float]:
    a = np.asarray(values_ms, dtype=np.float64)
    return {'n': int(a.size), 'median_ms': float(np.median(a)) if a.size else float('nan'),
            'p99_ms': float(np.percentile(a, 99)) if a.size else float('nan'),
            'max_ms': float(a.max()) if a.size else float('nan')}


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc; all its threads)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _probe_qos(depth: int, reliable: bool = True):
    """A reader with a history for a whole run: a busy probe delays samples, never overwrites
    them. Reliable: nothing lost in transport either (the publisher then also handles acks)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=(ReliabilityPolicy.RELIABLE if reliable
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=DurabilityPolicy.VOLATILE)


class Probe:
    """The benchmark's own rclpy node."""

    def __init__(self, domain: int) -> None:
        self.rclpy = rclpy
        rclpy.init(domain_id=domain)
        self.node = rclpy.create_node('bench_ros_probe')

    def spin_for(self, seconds: float, until=None) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not (until and until()):
            self.rclpy.spin_once(self.node, timeout_sec=0.005)

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.shutdown()


def bench_estimator(probe: Probe, hand, rates: list[float], seconds: float, pid: int,
                    wrench_reliable: bool, latency_seconds: float) -> dict:
    """`pid`: the estimator's process, whose CPU time per frame is reported too;
    `wrench_reliable`: the probe reads the 18 wrench topics reliably (else best-effort, as the
    project's sensor-data subscribers do)."""
    node = probe.node
    publisher = node.create_publisher(TactileHand, TOPIC_TACTILE, publisher_qos(TOPIC_TACTILE))
    n_arrays = len(hand.arrays)
    depth = int(max(rates + [RATE_HZ]) * max(seconds, latency_seconds)) + 100
    # frame stamp -> [(reception, source) ns of each wrench]; estimate stamps as received
    wrenches: dict[int, list[tuple[int, int]]] = {}
    estimates: list[int] = []

    def on_wrench(raw: bytes, info) -> None:
        wrenches.setdefault(_stamp_of(raw), []).append(
            (info['received_timestamp'], info['source_timestamp']))

    wrench_subs = [node.create_subscription(WrenchStamped, array_wrench_topic(a.name),
                                            on_wrench, _probe_qos(depth, wrench_reliable),
                                            raw=True)
                   for a in hand.arrays]
    node.create_subscription(ForceEstimateArray, TOPIC_ESTIMATES,
                             lambda raw: estimates.append(_stamp_of(raw)), _probe_qos(depth),
                             raw=True)
    # A few distinct frames, serialized once: per send only the stamp is written.
    rng = np.random.default_rng(0)
    base = rng.uniform(15000, 30000, size=(hand.n_taxels, 3))
    frames = [bytearray(serialize_message(tactile_hand(
        0, hand, np.clip(base + rng.normal(0, 3, base.shape), 0, 65535).astype(np.uint16),
        None, 0.0, k))) for k in range(16)]

    def send(count: int, rate: float) -> list[int]:
        sent, period = [], 1.0 / rate
        next_t = time.monotonic()
        for k in range(count):
            frame = frames[k % len(frames)]
            now = time.time_ns()    # the rmw's timestamps are wall clock too
            _STAMP.pack_into(frame, _STAMP_AT, *divmod(now, 1_000_000_000))
            publisher.publish(bytes(frame))
            sent.append(now)
            next_t += period
            # Spin while waiting: the probe also receives meanwhile.
            while time.monotonic() < next_t:
                probe.rclpy.spin_once(node, timeout_sec=max(0.0, next_t - time.monotonic()))
        return sent

    # Warm-up until the estimator answers (start-up, discovery, tare on the first frames): a
    # loaded machine can take many seconds, and frames sent before that would count as lost.
    deadline = time.monotonic() + WARM_UP_TIMEOUT_S
    while not estimates:
        if time.monotonic() > deadline:
            raise RuntimeError(
                f'the estimator published no estimate within {WARM_UP_TIMEOUT_S:.0f} s of '
                f'frames at {RATE_HZ:g} Hz; {TOPIC_TACTILE} matched '
                f'{publisher.get_subscription_count()} subscription(s), {TOPIC_ESTIMATES} '
                f'{node.count_publishers(TOPIC_ESTIMATES)} publisher(s)')
        send(10, RATE_HZ)
    send(int(RATE_HZ), RATE_HZ)     # a second, steady, so start-up work is over before timing
    probe.spin_for(0.5)
    wrenches.clear()
    estimates.clear()
    cpu = _cpu_seconds(pid)
    sent = send(int(RATE_HZ * latency_seconds), RATE_HZ)
    cpu = _cpu_seconds(pid) - cpu
    probe.spin_for(1.0)
    complete = [(s, wrenches[s]) for s in sent if len(wrenches.get(s, ())) == n_arrays]
    ms = 1e-6
    latency = _percentiles([(max(r for r, _ in w) - s) * ms for s, w in complete])
    latency.update(
        frames=len(sent), complete=len(complete), rate_hz=RATE_HZ,
        cpu_ms_per_frame=cpu * 1e3 / len(sent),
        # frame stamp -> first wrench leaves the estimator: transport in, wake-up, decode,
        # estimate; first -> last wrench leaves: the 18 publishes
        to_first_publish=_percentiles([(min(o for _, o in w) - s) * ms for s, w in complete]),
        # frame stamp -> last wrench leaves: the estimator's in -> out, without the delivery
        to_last_publish=_percentiles([(max(o for _, o in w) - s) * ms for s, w in complete]),
        publish_span=_percentiles([(max(o for _, o in w) - min(o for _, o in w)) * ms
                                   for _, w in complete]))
    # The rate test counts ForceEstimateArray only: it is published after the 18 wrenches of
    # its frame, so each one received is a frame the estimator handled in full.
    for sub in wrench_subs:
        node.destroy_subscription(sub)
    sustained = []
    for rate in rates:
        estimates.clear()
        t0, cpu = time.monotonic(), _cpu_seconds(pid)
        sent = send(int(rate * seconds), rate)
        elapsed, cpu = time.monotonic() - t0, _cpu_seconds(pid) - cpu
        probe.spin_for(1.0)
        got = len(set(estimates) & set(sent))
        # Estimates carry their frame's stamp; "stale" ones (stamped with the node clock) do not
        # match a sent frame and are not counted.
        sustained.append({'rate_hz': rate, 'achieved_send_hz': len(sent) / elapsed,
                          'frames': len(sent), 'estimates': got, 'drops': len(sent) - got,
                          'cpu_ms_per_frame': cpu * 1e3 / len(sent)})
    return {'latency': latency, 'sustained': sustained}


def bench_controller(probe: Probe, rate: float, seconds: float) -> dict:
    stamps: list[int] = []
    sub = probe.node.create_subscription(
        ControllerState, TOPIC_CONTROLLER_STATE, lambda raw: stamps.append(_stamp_of(raw)),
        _probe_qos(int(rate * (seconds + 30.0))), raw=True)
    probe.spin_for(30.0, until=lambda: len(stamps) > 10)
    if len(stamps) <= 10:
        probe.node.destroy_subscription(sub)
        raise RuntimeError(f'{len(stamps)} controller states within 30 s: the controller '
                           'is not running')
    stamps.clear()
    probe.spin_for(seconds)
    probe.node.destroy_subscription(sub)
    periods_ms = np.diff(np.sort(np.asarray(stamps, dtype=np.int64))) * 1e-6
    nominal = 1e3 / rate
    jitter = np.abs(periods_ms - nominal)
    return {'rate_hz': rate, 'ticks': int(len(stamps)),
            'mean_period_ms': float(periods_ms.mean()) if periods_ms.size else float('nan'),
            'jitter_p99_ms': float(np.percentile(jitter, 99)) if jitter.size else float('nan'),
            'jitter_max_ms': float(jitter.max()) if jitter.size else float('nan')}
