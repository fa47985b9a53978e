"""bench_devices: end-to-end latency (emulator send -> driver callback) and sustained rates of
the three device links over loopback, in one process on one monotonic clock.

Each emulator logs (sequence, monotonic send time); the sequence travels on the wire (XELA
``message``, RDT ``rdt_sequence``, and for CAN a cycle counter encoded in joint 0's pose) and the
driver callback looks its send time up. Writes JSON (``--out``) and prints a table.
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from tacforce_ros.devices.allegro import AllegroConfig, AllegroV4Driver
from tacforce_ros.devices.allegro_codec import RAD_PER_COUNT
from tacforce_ros.devices.netft import NetFtClient, NetFtConfig
from tacforce_ros.devices.polling import PollingDriver
from tacforce_ros.devices.xela import XelaClient, XelaConfig
from tacforce_ros.hand.description import load_hand
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.paths import output_file
from tacforce_ros.sim.emulators.allegro import AllegroEmulator
from tacforce_ros.sim.emulators.netft import NetFtEmulator
from tacforce_ros.sim.emulators.xela_server import XelaServerEmulator

DEVICES = ('xela', 'netft', 'allegro')
FIRST_SAMPLE_TIMEOUT_S = 30.0


def _measure(driver: PollingDriver, sent_log, sequence_of: Callable, duration: float,
             rate_hz: float, frames_per_sample: int, modulo: int | None = None) -> dict:
    """Run ``driver`` in its background thread for ``duration`` s from its first sample (waited
    for up to FIRST_SAMPLE_TIMEOUT_S: connecting is not the link's rate) and summarise the link;
    ``modulo`` when the wire carries the sequence number modulo that value."""
    arrivals: list[tuple[int, float]] = []
    first = threading.Event()

    def arrived(sample) -> None:
        arrivals.append((sequence_of(sample), time.monotonic()))
        first.set()
    driver.add_callback(arrived)
    driver.start()
    if first.wait(FIRST_SAMPLE_TIMEOUT_S):
        time.sleep(duration)
    else:
        print(f'bench_devices: {type(driver).__name__} delivered no sample within '
              f'{FIRST_SAMPLE_TIMEOUT_S:g} s; its row shows nothing delivered', file=sys.stderr)
    driver.close()
    sent = {(k % modulo if modulo else k): t for k, t in list(sent_log)}
    latencies = np.array([(t - sent[k]) * 1e6 for k, t in arrivals if k in sent])
    diag = driver.diagnostics.snapshot()
    span = arrivals[-1][1] - arrivals[0][1] if len(arrivals) > 1 else float('nan')
    delivered_in_span = {k for k, _ in arrivals}
    first, last = (min(delivered_in_span), max(delivered_in_span)) if arrivals else (0, -1)
    expected = sum(1 for k in sent if first <= k <= last)
    return {
        'rate_configured_hz': rate_hz,
        'rate_measured_hz': (len(arrivals) - 1) / span if len(arrivals) > 1 else 0.0,
        'frames_per_s': frames_per_sample * (len(arrivals) - 1) / span if len(arrivals) > 1
        else 0.0,
        'sent': len(sent), 'delivered': len(arrivals),
        'lost_between_first_and_last': expected - len(delivered_in_span),
        'gaps': diag.gaps, 'malformed': diag.malformed, 'dropped': diag.dropped,
        'latency_us': {
            'n': int(latencies.size),
            'median': float(np.median(latencies)) if latencies.size else float('nan'),
            'p99': float(np.percentile(latencies, 99)) if latencies.size else float('nan'),
            'max': float(latencies.max()) if latencies.size else float('nan')},
    }


def bench_xela(duration: float, rate_hz: float) -> dict:
    rng = np.random.default_rng(0)
    counts = rng.integers(30000, 40000, size=(368, 3)).astype(np.uint16)
    temps = np.full(368, 300.0)
    with XelaServerEmulator(lambda: (counts, temps, time.time()), rate_hz=rate_hz) as server:
        client = XelaClient(XelaConfig(url=server.url), load_hand())
        result = _measure(client, server.sent_log, lambda f: f.sequence, duration, rate_hz, 1)
    return {'device': 'xela', 'transport': 'WebSocket JSON, 368 taxels', **result}


def bench_netft(duration: float, rate_hz: float) -> dict:
    counts = np.array([1, 2, 3, 4, 5, 6], np.int32) * 100_000
    with NetFtEmulator(lambda: (counts, 0), rate_hz=rate_hz) as box:
        host, port = box.address
        client = NetFtClient(NetFtConfig(host=host, port=port))
        result = _measure(client, box.sent_log, lambda s: s.rdt_sequence, duration, rate_hz, 1)
    return {'device': 'netft', 'transport': 'UDP RDT, 36-byte records', **result}


def bench_allegro(duration: float, period_ms: int) -> dict:
    cycle = [0]
    lock = threading.Lock()

    def joint_source() -> np.ndarray:
        # Joint 0 carries the cycle number (mod 2**15) so the receiver can find its send time.
        with lock:
            q = np.zeros(16)
            q[0] = (cycle[0] % 32768) * RAD_PER_COUNT
            cycle[0] += 1
        return q

    with AllegroEmulator(joint_source, lambda tau: None) as hand:
        kwargs = hand.bus_kwargs()
        config = AllegroConfig(interface=kwargs.pop('interface'), channel=kwargs.pop('channel'),
                               bus_kwargs=kwargs, rtr_requests=False,
                               position_period_ms=period_ms)
        driver = AllegroV4Driver(config)
        result = _measure(driver, hand.sent_log, lambda s: int(s.counts[0]), duration,
                          1000.0 / period_ms, 4, modulo=32768)
    return {'device': 'allegro', 'transport': 'CAN via python-can socketcand (TCP)', **result}


def print_table(results: list[dict]) -> None:
    header = (f'{"device":8} {"rate Hz (cfg)":>14} {"rate Hz":>9} {"frames/s":>9} '
              f'{"sent":>7} {"deliv":>7} {"lost":>5} {"gaps":>5} {"median us":>10} '
              f'{"p99 us":>9} {"max us":>9}')
    print(header)
    print('-' * len(header))
    for r in results:
        lat = r['latency_us']
        print(f'{r["device"]:8} {r["rate_configured_hz"]:14.1f} {r["rate_measured_hz"]:9.1f} '
              f'{r["frames_per_s"]:9.1f} {r["sent"]:7d} {r["delivered"]:7d} '
              f'{r["lost_between_first_and_last"]:5d} {r["gaps"]:5d} {lat["median"]:10.1f} '
              f'{lat["p99"]:9.1f} {lat["max"]:9.1f}')


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--duration', type=float, default=5.0,
                        help='seconds per device, from its first sample')
    parser.add_argument('--devices', nargs='+', choices=DEVICES, default=list(DEVICES))
    parser.add_argument('--xela-rate', type=float, default=RATE_HZ, help='XELA frames/s')
    parser.add_argument('--rdt-rate', type=float, default=1000.0, help='RDT records/s')
    parser.add_argument('--allegro-period-ms', type=int, default=3,
                        help='FINGER_POSE period (3 ms = 333 Hz x 4 frames)')
    parser.add_argument('--out', type=output_file, help='write the results as JSON here')
    args = parser.parse_args(argv)
    runners = {'xela': lambda: bench_xela(args.duration, args.xela_rate),
               'netft': lambda: bench_netft(args.duration, args.rdt_rate),
               'allegro': lambda: bench_allegro(args.duration, args.allegro_period_ms)}
    results = [runners[name]() for name in args.devices]
    print_table(results)
    if args.out is not None:
        args.out.write_text(json.dumps({
            'duration_s': args.duration, 'python': platform.python_version(),
            'machine': platform.machine(), 'results': results}, indent=2))
        print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
