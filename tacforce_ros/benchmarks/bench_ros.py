"""bench_ros: the ROS layer's speed over real DDS, as JSON (--out) plus a table.

1. latency: tactile frame in -> all 18 WrenchStamped out through the estimator node (a model on
   every array), at 100 Hz for --latency-seconds: median and p99 of (reception of the frame's
   last wrench - the frame's stamp), split into the estimator's part (its first and last wrench
   publish times); once on the normal scheduler, and once with the estimator's
   realtime_priority parameter and the probe's threads (standing in for a consumer that is
   real-time too, e.g. force_controller with realtime_priority) at SCHED_FIFO --realtime-priority
   (skipped when 0 or refused). On the normal scheduler the tail is mostly wake-up delay: a
   woken DDS thread waits up to a scheduler tick (~4 ms) for a core held by another process;
2. sustained input: frames published at each --rates value for --seconds; ForceEstimateArray
   messages received vs frames sent (drops), and the rate achieved;
3. controller loop: force_controller and allegro_driver against sim_world's hand emulator,
   periods of /force_controller/state stamps at 100 Hz and 333 Hz: mean, p99 |period - nominal|.

The probe measures the estimator, not itself: it publishes frames serialized in advance (only
the stamp is written per frame), takes every message serialized (no Python message objects),
and times each by the rmw's own reception and source timestamps (taken by the DDS layer as the
sample arrives or leaves, not when Python gets to it); its readers are reliable with histories
deep enough for a whole run, so a busy probe delays samples but loses none (the estimator's
publishers are reliable too). All nodes run as separate processes on their own DDS domain
(ROS_AUTOMATIC_DISCOVERY_RANGE LOCALHOST); the probe node is this process. Wall clock
throughout (no sim time). Every run stops its nodes with SIGINT. Numbers depend on the
machine's load (the JSON records the load average): compare within one run.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from tacforce_ros.devices.allegro import MAX_JOINT_RATE_HZ
from tacforce_ros.estimation.model_set import write_synthetic_model_set
from tacforce_ros.hand.description import load_hand
from tacforce_ros.nodes.realtime import use_realtime_scheduling
from tacforce_ros.nodes.latency_probe import Probe, bench_controller, bench_estimator
from tacforce_ros.bringup.session_plan import NodeLaunch, params_file
from tacforce_ros.paths import output_file
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.bringup.processes import (first_exited, interrupt_on_sigterm, start_nodes,
                                           stop_nodes)

LATENCY_TARGET_P99_MS = 2.0
RATE_TARGET_HZ = 1000.0
def table(result: dict) -> str:
    lines = ['| measurement | value | target |', '|---|---|---|']
    for key in ('estimator', 'estimator_realtime'):
        if key not in result:
            continue
        if 'latency' not in result[key]:
            (outcome, why), = result[key].items()         # skipped or failed, and why
            lines.append(f'| {key} | {outcome.upper()}: {why} | |')
            continue
        lat = result[key]['latency']
        first, span = lat['to_first_publish'], lat['publish_span']
        prio = result[key]['realtime_priority']
        how = f'SCHED_FIFO {prio} (estimator and probe)' if prio else 'normal scheduler'
        last = lat['to_last_publish']
        lines += [
            f"| tactile -> 18 wrenches latency, {how}, median (100 Hz, {lat['complete']}/"
            f"{lat['frames']} frames complete) | {lat['median_ms']:.2f} ms | |",
            f"| tactile -> 18 wrenches latency, {how}, p99 (max) | {lat['p99_ms']:.2f} ms "
            f"({lat['max_ms']:.2f} ms) | <= {LATENCY_TARGET_P99_MS:g} ms |",
            f"| frame -> last wrench sent by the estimator, median / p99 | "
            f"{last['median_ms']:.2f} / {last['p99_ms']:.2f} ms | |",
            f"| of which frame -> first wrench sent, median / p99 | {first['median_ms']:.2f} / "
            f"{first['p99_ms']:.2f} ms | |",
            f"| of which first -> last wrench sent, median / p99 | {span['median_ms']:.2f} / "
            f"{span['p99_ms']:.2f} ms | |",
            f"| estimator CPU time per frame at 100 Hz (all its threads) | "
            f"{lat['cpu_ms_per_frame']:.2f} ms | well under 1 ms |"]
        for s in result[key]['sustained']:
            lines.append(f"| input {s['rate_hz']:g} Hz (sent at {s['achieved_send_hz']:.0f} Hz),"
                         f" {how}: drops (CPU per frame) | {s['drops']} of {s['frames']} "
                         f"({s['cpu_ms_per_frame']:.2f} ms) | 0 at >= {RATE_TARGET_HZ:g} Hz |")
    controller = result.get('controller', [])
    if isinstance(controller, dict):       # failed
        lines.append(f"| controller | FAILED: {controller['failed']} | |")
        controller = []
    for c in controller:
        lines.append(f"| controller {c['rate_hz']:g} Hz: mean period / jitter p99 | "
                     f"{c['mean_period_ms']:.2f} ms / {c['jitter_p99_ms']:.2f} ms | |")
    load = result['load_average']
    lines.append(f"| load average (1 min) before / after, {result['cpus']} CPUs | "
                 f"{load['before'][0]:.2f} / {load['after'][0]:.2f} | |")
    return '\n'.join(lines)


def run_estimator(probe: Probe, hand, args: argparse.Namespace, env: dict, tmp: Path,
                  priority: int) -> dict:
    """One latency and sustained-rate run; `priority` > 0: the estimator's realtime_priority,
    and the probe's threads at SCHED_FIFO `priority` while it measures.

    The estimator is started while the probe is still on the normal scheduler: a child process
    inherits the policy of the thread that forks it, so a probe at SCHED_FIFO would start the
    estimator's whole start-up (imports, DDS discovery, model loading) at SCHED_FIFO too,
    competing with the probe's own real-time threads on a 2-core machine before the node ever
    chose its priority (it raises itself once its node exists)."""
    models = write_synthetic_model_set(tmp / 'models', hand)
    procs = start_nodes([NodeLaunch('estimator', (params_file('estimator'),), {
        'model_config': str(models), 'tare_at_start': False, 'marker_rate_hz': 0.0,
        'realtime_priority': priority,
        # synthetic models are no calibration of the probe's frames (their spreads are a few
        # counts): the range check would flag every array, and no wrench would be published
        'out_of_range': 0.0})], tmp / 'logs', env)
    measured = False
    try:
        if priority > 0:
            use_realtime_scheduling(priority)
        if procs[0][1].poll() is not None:
            raise RuntimeError(f'the estimator exited at start-up with code '
                               f'{procs[0][1].returncode}')
        result = bench_estimator(probe, hand, args.rates, args.seconds, procs[0][1].pid,
                                 args.reliable_wrenches, args.latency_seconds)
        measured = True
        # What the estimator process runs at, read from the system (it may have been refused).
        pid = procs[0][1].pid
        result['realtime_priority'] = (os.sched_getparam(pid).sched_priority
                                       if os.sched_getscheduler(pid) == os.SCHED_FIFO else 0)
        return result
    finally:
        if priority > 0:
            use_realtime_scheduling(0)
        codes = stop_nodes(procs, grace=10.0)
        if not measured or any(codes.values()):      # the estimator's side of the story
            print((tmp / 'logs' / 'estimator.log').read_text()[-2000:])


def run_controller(probe: Probe, args: argparse.Namespace, env: dict, tmp: Path) -> list[dict]:
    out = []
    xela, netft, can = args.ports
    for rate in (RATE_HZ, MAX_JOINT_RATE_HZ):     # the frame rate; the hand's fastest stream
        procs = start_nodes([
            NodeLaunch('sim_world', (params_file('sim_world'),), {
                'publish_clock': False, 'lockstep': False, 'xela_port': xela,
                'netft_port': netft, 'can_port': can}),
            NodeLaunch('allegro_driver', (params_file('allegro_driver'),), {
                'interface': 'socketcand', 'channel': 'can0', 'host': '127.0.0.1',
                'port': can, 'rtr_requests': False}),
            NodeLaunch('force_controller', (params_file('force_controller'),),
                       {'control_rate_hz': rate})],
            tmp / 'logs', env)
        try:
            out.append(bench_controller(probe, rate, args.seconds))
        except RuntimeError as exc:
            exited = first_exited(procs)
            if exited is None:
                raise
            log = (tmp / 'logs' / f'{exited[0]}.log').read_text().strip().splitlines()
            raise RuntimeError(f'{exited[0]} exited with code {exited[1]}'
                               + (f': {log[-1]}' if log else '')) from exc
        finally:
            stop_nodes(procs, grace=10.0)
    return out


class RealtimeRefused(Exception):
    """SCHED_FIFO is not available here: the real-time run is skipped, not failed."""


def attempt(part: Callable[[], object]) -> object:
    """A part's result, {'skipped': why} or {'failed': why}: one part that fails keeps the
    others' results."""
    try:
        return part()
    except RealtimeRefused as exc:
        return {'skipped': str(exc)}
    except (RuntimeError, OSError, TimeoutError) as exc:
        return {'failed': f'{type(exc).__name__}: {exc}'}


def run_realtime_estimator(probe: Probe, hand, args: argparse.Namespace, env: dict,
                           tmp: Path) -> dict:
    """The latency run with the estimator and the probe on SCHED_FIFO; skipped, with the reason,
    where the system refuses it to the probe or the estimator did not get it."""
    try:
        use_realtime_scheduling(args.realtime_priority)     # allowed here at all?
    except OSError as exc:
        raise RealtimeRefused(f'SCHED_FIFO refused to the probe ({exc})') from None
    finally:
        use_realtime_scheduling(0)
    realtime = run_estimator(probe, hand, args, env, tmp, args.realtime_priority)
    if realtime['realtime_priority'] == 0:
        raise RealtimeRefused('the estimator ran without SCHED_FIFO (refused to it)')
    return realtime


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog='bench_ros', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=output_file, default=None, help='JSON result file')
    parser.add_argument('--seconds', type=float, default=3.0, help='per measurement')
    parser.add_argument('--latency-seconds', type=float, default=20.0,
                        help='length of the latency test at 100 Hz (p99 of 100 frames a second)')
    parser.add_argument('--realtime-priority', type=int, default=50,
                        help='estimator realtime_priority of the second latency run; 0 = none')
    parser.add_argument('--rates', type=float, nargs='+', default=[200.0, 500.0, 1000.0],
                        help='input rates of the sustained-rate test (Hz)')
    parser.add_argument('--parts', nargs='+', default=['estimator', 'controller'],
                        choices=['estimator', 'controller'], help='what to measure')
    parser.add_argument('--reliable-wrenches', action='store_true',
                        help='read the 18 wrench topics reliably (default: best-effort, the '
                        'sensor-data QoS of the project\'s own subscribers)')
    parser.add_argument('--domain', type=int, default=90 + os.getpid() % 10,
                        help='ROS_DOMAIN_ID of the benchmark graph')
    parser.add_argument('--ports', type=int, nargs=3, default=[25101, 25102, 25103],
                        help='emulator ports on 127.0.0.1 for the controller test')
    args = parser.parse_args(argv)
    interrupt_on_sigterm()      # its finally blocks stop the processes it started
    if args.seconds <= 0 or args.latency_seconds <= 0 or any(r <= 0 for r in args.rates):
        parser.error('--seconds, --latency-seconds and --rates must be positive')
    if not 0 <= args.realtime_priority <= 98:
        parser.error('--realtime-priority must be 0..98')
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env = dict(os.environ)
    hand = load_hand()
    result: dict = {'seconds': args.seconds, 'cpus': os.cpu_count(),
                    'reliable_wrenches': args.reliable_wrenches,
                    'load_average': {'before': os.getloadavg()}}
    probe = Probe(args.domain)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            if 'estimator' in args.parts:
                result['estimator'] = attempt(
                    lambda: run_estimator(probe, hand, args, env, Path(tmp), 0))
                if args.realtime_priority > 0:
                    result['estimator_realtime'] = attempt(
                        lambda: run_realtime_estimator(probe, hand, args, env, Path(tmp)))
            if 'controller' in args.parts:
                result['controller'] = attempt(lambda: run_controller(probe, args, env,
                                                                      Path(tmp)))
    finally:
        probe.close()
    result['load_average']['after'] = os.getloadavg()
    text = table(result)
    print(text)
    if args.out is not None:
        args.out.write_text(json.dumps({**result, 'table': text}, indent=2))
        print(f'wrote {args.out}')
    failed = [part for part, value in result.items()
              if isinstance(value, dict) and 'failed' in value]
    if failed:
        sys.exit(f'bench_ros: {", ".join(failed)} failed: ' + '; '.join(
            result[part]['failed'] for part in failed))


if __name__ == '__main__':
    main()
