"""bench_ros: the ROS layer's speed over real DDS, as JSON (--out) plus a table.

1. latency: tactile frame in -> all 18 WrenchStamped out through the estimator node (a model on
   every array), at 100 Hz: median and p99 of (arrival of the frame's last wrench - its stamp);
2. sustained input: frames published at each --rates value for --seconds; ForceEstimateArray
   messages received vs frames sent (drops), and the rate achieved;
3. controller loop: allegro_driver (force control) against sim_world's hand emulator, periods
   of /force_controller/state stamps at 100 Hz and 333 Hz: mean, p99 |period - nominal|.

All nodes run as separate processes on their own DDS domain (ROS_AUTOMATIC_DISCOVERY_RANGE
LOCALHOST); the probe node is this process. Wall clock throughout (no sim time). Every run
stops its nodes with SIGINT. Numbers depend on the machine's load: compare within one run.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.model_set import write_synthetic_model_set
from tacforce_ros.nodes.session_plan import NodeLaunch, params_file
from tacforce_ros.tools.session import start_nodes, stop_nodes

LATENCY_TARGET_P99_MS = 2.0
RATE_TARGET_HZ = 1000.0


def _percentiles(values_ms: list[float]) -> dict[str, float]:
    a = np.asarray(values_ms, dtype=np.float64)
    return {'n': int(a.size), 'median_ms': float(np.median(a)) if a.size else float('nan'),
            'p99_ms': float(np.percentile(a, 99)) if a.size else float('nan'),
            'max_ms': float(a.max()) if a.size else float('nan')}


class Probe:
    """The benchmark's own rclpy node (imported lazily: only nodes/ and this tool touch rclpy)."""

    def __init__(self, domain: int) -> None:
        import rclpy
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


def bench_estimator(probe: Probe, hand, rates: list[float], seconds: float) -> dict:
    from geometry_msgs.msg import WrenchStamped
    from tacforce_msgs.msg import ForceEstimateArray, TactileHand
    from tacforce_ros.nodes.common import publisher_qos, subscriber_qos
    from tacforce_ros.nodes.messages import stamp_ns, tactile_hand

    node = probe.node
    publisher = node.create_publisher(TactileHand, '/tactile/raw', publisher_qos('/tactile/raw'))
    n_arrays = len(hand.arrays)
    arrivals: dict[int, list[int]] = {}
    estimates: list[int] = []

    def on_wrench(msg: WrenchStamped) -> None:
        arrivals.setdefault(stamp_ns(msg.header.stamp), []).append(time.time_ns())

    wrench_subs = [node.create_subscription(WrenchStamped, f'/tactile/{a.name}/wrench',
                                            on_wrench, subscriber_qos(f'/tactile/{a.name}/wrench'))
                   for a in hand.arrays]
    node.create_subscription(ForceEstimateArray, '/tactile/estimates',
                             lambda m: estimates.append(stamp_ns(m.header.stamp)),
                             subscriber_qos('/tactile/estimates'))
    rng = np.random.default_rng(0)
    base = rng.uniform(15000, 30000, size=(hand.n_taxels, 3))

    def send(count: int, rate: float) -> list[int]:
        sent, period = [], 1.0 / rate
        next_t = time.monotonic()
        for k in range(count):
            counts = np.clip(base + rng.normal(0, 3, base.shape), 0, 65535).astype(np.uint16)
            now = time.time_ns()
            publisher.publish(tactile_hand(now, hand, counts, None, now * 1e-9, k + 1))
            sent.append(now)
            next_t += period
            # Spin while waiting: the probe also receives meanwhile.
            while time.monotonic() < next_t:
                probe.rclpy.spin_once(node, timeout_sec=max(0.0, next_t - time.monotonic()))
        return sent

    # Warm-up until the estimator answers (discovery, tare on the first frames).
    send(100, 100.0)
    probe.spin_for(2.0, until=lambda: len(estimates) > 0)
    arrivals.clear()
    estimates.clear()
    sent = send(int(100.0 * seconds), 100.0)
    probe.spin_for(1.0)
    complete = [max(arrivals[s]) - s for s in sent if len(arrivals.get(s, ())) == n_arrays]
    latency = _percentiles([ns * 1e-6 for ns in complete])
    latency.update(frames=len(sent), complete=len(complete), rate_hz=100.0)
    # The rate test counts ForceEstimateArray only: 18 more Python subscriptions in the probe
    # would make the probe, not the estimator, the bottleneck.
    for sub in wrench_subs:
        node.destroy_subscription(sub)
    sustained = []
    for rate in rates:
        estimates.clear()
        t0 = time.monotonic()
        sent = send(int(rate * seconds), rate)
        elapsed = time.monotonic() - t0
        probe.spin_for(1.0)
        got = len(set(estimates) & set(sent))
        # Estimates carry their frame's stamp; "stale" ones (stamped with the node clock) do not
        # match a sent frame and are not counted.
        sustained.append({'rate_hz': rate, 'achieved_send_hz': len(sent) / elapsed,
                          'frames': len(sent), 'estimates': got, 'drops': len(sent) - got})
    return {'latency': latency, 'sustained': sustained}


def bench_controller(probe: Probe, rate: float, seconds: float) -> dict:
    from tacforce_msgs.msg import ControllerState
    from tacforce_ros.nodes.common import subscriber_qos
    from tacforce_ros.nodes.messages import stamp_ns

    stamps: list[int] = []
    sub = probe.node.create_subscription(
        ControllerState, '/force_controller/state',
        lambda m: stamps.append(stamp_ns(m.header.stamp)),
        subscriber_qos('/force_controller/state'))
    probe.spin_for(30.0, until=lambda: len(stamps) > 10)
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


def table(result: dict) -> str:
    lat = result['estimator']['latency']
    lines = ['| measurement | value | target |', '|---|---|---|',
             f"| tactile -> 18 wrenches latency, median (100 Hz, {lat['complete']}/"
             f"{lat['frames']} frames complete) | {lat['median_ms']:.2f} ms | |",
             f"| tactile -> 18 wrenches latency, p99 | {lat['p99_ms']:.2f} ms | "
             f"<= {LATENCY_TARGET_P99_MS:g} ms |"]
    for s in result['estimator']['sustained']:
        lines.append(f"| input {s['rate_hz']:g} Hz (sent at {s['achieved_send_hz']:.0f} Hz): "
                     f"drops | {s['drops']} of {s['frames']} | 0 at >= {RATE_TARGET_HZ:g} Hz |")
    for c in result['controller']:
        lines.append(f"| controller {c['rate_hz']:g} Hz: mean period / jitter p99 | "
                     f"{c['mean_period_ms']:.2f} ms / {c['jitter_p99_ms']:.2f} ms | |")
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog='bench_ros', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=Path, default=None, help='JSON result file')
    parser.add_argument('--seconds', type=float, default=3.0, help='per measurement')
    parser.add_argument('--rates', type=float, nargs='+', default=[200.0, 500.0, 1000.0],
                        help='input rates of the sustained-rate test (Hz)')
    parser.add_argument('--domain', type=int, default=90 + os.getpid() % 10,
                        help='ROS_DOMAIN_ID of the benchmark graph')
    parser.add_argument('--ports', type=int, nargs=3, default=[25101, 25102, 25103],
                        help='emulator ports on 127.0.0.1 for the controller test')
    args = parser.parse_args(argv)
    if args.seconds <= 0 or any(r <= 0 for r in args.rates):
        parser.error('--seconds and --rates must be positive')
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env = dict(os.environ)
    hand = load_hand()
    result: dict = {'seconds': args.seconds}
    probe = Probe(args.domain)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            models = write_synthetic_model_set(Path(tmp) / 'models', hand)
            procs = start_nodes([NodeLaunch('estimator', (params_file('estimator'),), {
                'model_config': str(models), 'tare_at_start': False,
                'marker_rate_hz': 0.0})], Path(tmp) / 'logs', 30.0, env)
            try:
                result['estimator'] = bench_estimator(probe, hand, args.rates, args.seconds)
            finally:
                codes = stop_nodes(procs, grace=10.0)
                if any(codes.values()):
                    print((Path(tmp) / 'logs' / 'estimator.log').read_text()[-2000:])
            result['controller'] = []
            xela, netft, can = args.ports
            for rate in (100.0, 1000.0 / 3.0):
                procs = start_nodes([
                    NodeLaunch('sim_world', (params_file('sim_world'),), {
                        'publish_clock': False, 'xela_port': xela, 'netft_port': netft,
                        'can_port': can}, ready_port=can),
                    NodeLaunch('allegro_driver', (params_file('allegro_driver'),
                                                  params_file('force_controller')), {
                        'interface': 'socketcand', 'channel': 'can0', 'host': '127.0.0.1',
                        'port': can, 'rtr_requests': False, 'control_rate_hz': rate})],
                    Path(tmp) / 'logs', 30.0, env)
                try:
                    result['controller'].append(bench_controller(probe, rate, args.seconds))
                finally:
                    stop_nodes(procs, grace=10.0)
    finally:
        probe.close()
    text = table(result)
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({**result, 'table': text}, indent=2))
        print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
