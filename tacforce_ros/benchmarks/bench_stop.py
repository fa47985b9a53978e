"""bench_stop: does every node, and the `session` tool, end soon after SIGINT or SIGTERM?

Each subject is started `--stops` times and sent SIGINT or SIGTERM (in turn) at a random moment;
the time from the signal to the process's exit is measured, and a subject still running
`--kill-after` s after the signal is killed (SIGKILL) and counted as such. The stops cycle through
the conditions a user meets:

* the device: `streaming` (the simulator serves the emulated XELA server, Net F/T box and hand,
  and publishes /clock), `silent` or `gone`. To a subject that talks to devices (the lifecycle
  drivers, the container) silent means ports that accept and never answer (a device that hangs)
  and gone means nothing listens. To a node that reads topics silent means the drivers around it
  are deactivated (its inputs stop, /clock runs) and gone means the simulator was killed (no
  clock, and the drivers around end on their lost links);
* the moment: `starting` (a random moment within `--start-window` s of the process's start:
  loading, building the node, waiting for its clock or device), `running` (a random moment within
  1 s of the node answering its parameter service), and for the lifecycle drivers `unconfigured`,
  `inactive` and `active` (started with autostart false and driven there over their lifecycle
  services; a transition that cannot complete, a configure with no device, is given up after
  `--transition-timeout` s and the node signalled in whatever state it is).

Around a node that reads topics run the other nodes of a closed-loop session (free-running
simulated time), started again whenever they end; around a subject that talks to devices, the
simulator alone. The lifecycle drivers run on the wall clock (use_sim_time false, as on the
hardware), so that a device that hangs is that to them, not a clock that never starts. (A
process frozen with SIGSTOP is no stand-in: the DDS library's shared-memory transport then held
a new node's start-up for good.) `session` runs a closed-loop session with its own simulator; it
must stop every process it started.

Writes <out>/bench_stop.json (every stop) and bench_stop.md (per subject: stops, how many ended
within `--limit` s, the worst, median and 95th percentile, exit codes, and every stop that needed
SIGKILL or ended otherwise than with exit code 0, with the end of its log in the JSON; for
`session`, the ends of its nodes' logs too).
"""
from __future__ import annotations

import argparse
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from lifecycle_msgs.msg import Transition

from tacforce_ros import results
from tacforce_ros.bringup.processes import executable, interrupt_on_sigterm, start_nodes
from tacforce_ros.nodes.graph_probe import GraphProbe
from tacforce_ros.bringup.session_plan import NodeLaunch, SessionArgs, composed, plan
from tacforce_ros.paths import output_folder

MANAGED = ('xela_driver', 'ft_bridge', 'allegro_driver')
NODES = ('sim_world', 'xela_driver', 'ft_bridge', 'allegro_driver', 'estimator',
         'force_controller', 'command_player', 'sync_recorder', 'coverage_view')
SUBJECTS = NODES + ('tacforce_container', 'session')
DEVICES = ('streaming', 'silent', 'gone')
LIFECYCLE = ('unconfigured', 'inactive', 'active')
SIGNALS = (signal.SIGINT, signal.SIGTERM)
GRAPH_TIMEOUT_S = 30.0        # longest wait for a subject to answer in the graph
CLOCK_TIMEOUT_S = 30.0        # longest wait for a restarted simulator's first /clock
SESSION_RUNNING_S = (5.0, 15.0)   # `session` signalled this many wall seconds after its start


@dataclass(frozen=True)
class Condition:
    device: str          # streaming | silent | gone | own (session: its own simulator)
    moment: str          # starting | running | unconfigured | inactive | active


def conditions(subject: str) -> list[Condition]:
    """The conditions a subject's stops cycle through, grouped by device state."""
    if subject == 'session':
        return [Condition('own', m) for m in ('starting', 'running')]
    if subject == 'sim_world':    # it is the device: its clients run, as in a session
        return [Condition('streaming', m) for m in ('starting', 'running')]
    moments = ('starting',) + (LIFECYCLE if subject in MANAGED else ('running',))
    return [Condition(d, m) for d in DEVICES for m in moments]


def schedule(subject: str, stops: int) -> list[Condition]:
    """`stops` conditions, each condition equally often (to within one), grouped by device so
    the simulator changes state as rarely as possible."""
    cycle = conditions(subject)
    picked = [cycle[k % len(cycle)] for k in range(stops)]
    return sorted(picked, key=lambda c: (DEVICES + ('own',)).index(c.device))


def closed_loop_nodes(ports: tuple[int, int, int], out: Path) -> dict[str, NodeLaunch]:
    """Every node of a closed-loop session by executable, and the calibration session's
    coverage_view; the simulator free-running (nothing waits for a subject that is down)."""
    args = SessionArgs(mode='closed_loop', lockstep=False, out=str(out), xela_port=ports[0],
                       netft_port=ports[1], can_port=ports[2])
    nodes = {n.executable: n for n in plan(args)}
    calibration = plan(replace(args, mode='calibration', plate='flat'))
    nodes['coverage_view'] = next(n for n in calibration if n.executable == 'coverage_view')
    return nodes


def subject_launch(subject: str, nodes: dict[str, NodeLaunch], moment: str) -> NodeLaunch:
    """How the subject is started for one stop."""
    if subject == 'tacforce_container':
        return composed([n for n in nodes.values() if n.executable not in ('coverage_view',)])[1]
    node = nodes[subject]
    if subject in MANAGED:
        return replace(node, overrides={**node.overrides, 'use_sim_time': False,
                                        'autostart': moment == 'starting'})
    return node


def background_for(subject: str) -> tuple[str, ...]:
    """The nodes that run around a subject: its device (the simulator) for the drivers and the
    container, which talk to devices; the whole graph for the nodes that read topics."""
    if subject == 'session':
        return ()
    if subject in MANAGED + ('tacforce_container',):
        return ('sim_world',)
    return tuple(n for n in NODES if n not in (subject, 'coverage_view'))


class MuteDevice:
    """The three device ports held by a device that hangs: the XELA server's and the hand's TCP
    ports accept a connection and never answer, the F/T box's UDP port takes requests and sends
    nothing."""

    def __init__(self, ports: tuple[int, int, int]) -> None:
        xela, netft, can = ports
        self.listeners = [socket.create_server(('127.0.0.1', port)) for port in (xela, can)]
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.bind(('127.0.0.1', netft))
        self.accepted: list[socket.socket] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        for listener in self.listeners:
            listener.settimeout(0.05)
        while not self._stop.is_set():
            for listener in self.listeners:
                try:
                    self.accepted.append(listener.accept()[0])     # kept open, never read
                except (TimeoutError, OSError):
                    continue

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        for sock in [*self.listeners, self.udp, *self.accepted]:
            sock.close()


class Background:
    """The nodes around the subject, and the state of its device (or of its inputs)."""

    def __init__(self, subject: str, nodes: dict[str, NodeLaunch], ports: tuple[int, int, int],
                 log_dir: Path, env: dict[str, str], graph: GraphProbe) -> None:
        self.names = background_for(subject)
        self.talks_to_devices = subject in MANAGED + ('tacforce_container',)
        self.nodes, self.ports, self.log_dir, self.env, self.graph = (nodes, ports, log_dir, env,
                                                                      graph)
        self.procs: dict[str, subprocess.Popen] = {}
        self.mute: MuteDevice | None = None
        self.drivers_inactive = False

    def _start(self, name: str) -> None:
        self.procs[name] = start_nodes([self.nodes[name]], self.log_dir, self.env, 'a')[0][1]

    def _running(self, name: str) -> bool:
        return name in self.procs and self.procs[name].poll() is None

    def _drivers(self, transition: int) -> None:
        for name in MANAGED:
            if name in self.names and self._running(name):
                self.graph.transitions(name, [transition], CLOCK_TIMEOUT_S)

    def device(self, state: str) -> None:
        """streaming: the simulator serves the devices and every node around runs (ended ones
        are started again). silent: to a subject that talks to devices, they accept and never
        answer (MuteDevice); to one that reads topics, the drivers around it are deactivated, so
        its inputs stop while /clock runs. gone: no simulator (the drivers around end on their
        lost links)."""
        if 'sim_world' not in self.names:       # the subject is the simulator: its clients run
            for name in self.names:
                if not self._running(name):
                    self._start(name)
            return
        if self.mute is not None and state != 'silent':
            self.mute.close()
            self.mute = None
        if state == 'gone' or (state == 'silent' and self.talks_to_devices):
            if self._running('sim_world'):
                self.procs['sim_world'].kill()
                self.procs['sim_world'].wait()
            if state == 'silent' and self.mute is None:
                self.mute = MuteDevice(self.ports)
            return
        if not self._running('sim_world'):
            self._start('sim_world')
            seen = self.graph.clock_seen
            if not self.graph.spin_until(lambda: self.graph.clock_seen > seen, CLOCK_TIMEOUT_S):
                raise RuntimeError(f'the simulator published no /clock within {CLOCK_TIMEOUT_S} s'
                                   f' (log in {self.log_dir})')
        for name in self.names:
            if not self._running(name):
                self._start(name)
                self.drivers_inactive &= name not in MANAGED
        if state == 'silent' and not self.drivers_inactive:
            self._drivers(Transition.TRANSITION_DEACTIVATE)
            self.drivers_inactive = True
        elif state == 'streaming' and self.drivers_inactive:
            self._drivers(Transition.TRANSITION_ACTIVATE)
            self.drivers_inactive = False

    def stop(self) -> None:
        if self.mute is not None:
            self.mute.close()
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in self.procs.values():
            try:
                proc.wait(timeout=15.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def descendants(pid: int) -> set[int]:
    """Every process below `pid` (Linux /proc children lists)."""
    found, todo = set(), [pid]
    while todo:
        parent = todo.pop()
        try:
            tasks = os.listdir(f'/proc/{parent}/task')
        except OSError:
            continue
        for task in tasks:
            try:
                children = Path(f'/proc/{parent}/task/{task}/children').read_text().split()
            except OSError:
                continue
            for child in map(int, children):
                if child not in found:
                    found.add(child)
                    todo.append(child)
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state != 'Z'


def tail(path: Path, lines: int = 12) -> str:
    try:
        return '\n'.join(path.read_text(errors='replace').splitlines()[-lines:])
    except OSError:
        return ''


def one_stop(k: int, subject: str, condition: Condition, signum: int, launch: NodeLaunch | None,
             args, graph: GraphProbe, env: dict[str, str], work: Path, rng: random.Random) -> dict:
    """Start the subject, signal it at a random moment of `condition`, time its end (the end of
    its log kept with any stop that was not clean and prompt)."""
    log = work / 'logs' / f'{subject}_{k}.log'
    log.parent.mkdir(parents=True, exist_ok=True)
    if subject == 'session':
        command = [str(executable('session')), 'closed_loop', '--out', str(work / f'session_{k}'),
                   '--ports', *map(str, args.session_ports)]
    else:
        command = [str(executable(launch.executable)), *launch.command_args()]
    with open(log, 'w') as out:
        proc = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)
    try:
        row = _stop_at_random(subject, condition, signum, proc, log, args, graph, rng)
        if subject == 'session' and 'log_tail' in row:     # and why: its nodes' own logs
            for child in sorted((work / f'session_{k}' / 'logs').glob('*.log')):
                row['log_tail'] += f'\n--- {child.name}\n' + tail(child, 6)
        return row
    finally:
        if proc.poll() is None:         # the benchmark itself was interrupted
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=args.kill_after)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _stop_at_random(subject: str, condition: Condition, signum: int, proc: subprocess.Popen,
                    log: Path, args, graph: GraphProbe, rng: random.Random) -> dict:
    started = time.monotonic()
    reached = ''
    if condition.moment == 'starting':
        delay = rng.uniform(0.0, args.start_window)
        time.sleep(delay)
    elif subject == 'session':
        time.sleep(rng.uniform(*SESSION_RUNNING_S))
    else:
        name = 'estimator' if subject == 'tacforce_container' else subject
        graph.answers(name, GRAPH_TIMEOUT_S, lambda: proc.poll() is None)
        if condition.moment in ('inactive', 'active'):
            reached = graph.lifecycle(name, condition.moment, args.transition_timeout)
        elif condition.moment == 'unconfigured':
            reached = 'unconfigured'
        time.sleep(rng.uniform(0.0, 1.0))
    delay = time.monotonic() - started
    children = descendants(proc.pid)
    ended_before = proc.poll() is not None
    signalled = time.monotonic()
    if not ended_before:
        proc.send_signal(signum)
    killed = False
    try:
        proc.wait(timeout=args.kill_after)
    except subprocess.TimeoutExpired:
        killed = True
        proc.kill()
        proc.wait()
    stop_s = time.monotonic() - signalled
    time.sleep(0.2)
    orphans = sorted(pid for pid in children if alive(pid))
    for pid in orphans:
        os.kill(pid, signal.SIGKILL)
    row = {'subject': subject, 'device': condition.device, 'moment': condition.moment,
           'reached': reached, 'signal': signal.Signals(signum).name,
           'after_start_s': round(delay, 3), 'ended_before_signal': ended_before,
           'stop_s': None if ended_before else round(stop_s, 3), 'exit_code': proc.returncode,
           'killed': killed, 'orphans': len(orphans)}
    if killed or ended_before or orphans or proc.returncode != 0 or stop_s > args.limit:
        row['log_tail'] = tail(log)
    return row


def run_subject(subject: str, args, env: dict[str, str], graph: GraphProbe, work: Path,
                rng: random.Random) -> list[dict]:
    nodes = closed_loop_nodes(tuple(args.ports), work / 'bags')
    background = Background(subject, nodes, tuple(args.ports), work / 'logs' / 'around', env,
                            graph)
    rows = []
    try:
        for k, condition in enumerate(schedule(subject, args.stops)):
            background.device('streaming' if condition.device == 'own' else condition.device)
            launch = None if subject == 'session' else subject_launch(subject, nodes,
                                                                      condition.moment)
            row = one_stop(k, subject, condition, SIGNALS[k % 2], launch, args, graph, env,
                           work, rng)
            rows.append(row)
            flag = ('KILLED' if row['killed'] else 'ended before the signal'
                    if row['ended_before_signal'] else f'{row["stop_s"]:.2f} s')
            print(f'bench_stop: {subject} {k + 1}/{args.stops} {condition.device}/'
                  f'{condition.moment}{"->" + row["reached"] if row["reached"] else ""} '
                  f'{row["signal"]} at {row["after_start_s"]:.2f} s: {flag}, exit '
                  f'{row["exit_code"]}' + (f', {row["orphans"]} orphans' if row['orphans']
                                           else ''), flush=True)
    finally:
        background.stop()
    return rows


def summary(rows: list[dict], limit: float) -> dict:
    times = np.array([r['stop_s'] for r in rows if r['stop_s'] is not None], dtype=float)
    codes: dict[str, int] = {}
    for r in rows:
        codes[str(r['exit_code'])] = codes.get(str(r['exit_code']), 0) + 1
    return {'stops': len(rows),
            'within_limit': int(sum(1 for r in rows if r['stop_s'] is not None
                                    and r['stop_s'] <= limit and not r['killed'])),
            'killed': sum(r['killed'] for r in rows),
            'ended_before_signal': sum(r['ended_before_signal'] for r in rows),
            'orphans': sum(r['orphans'] for r in rows),
            'worst_s': float(times.max()) if times.size else None,
            'median_s': float(np.median(times)) if times.size else None,
            'p95_s': float(np.percentile(times, 95)) if times.size else None,
            'exit_codes': codes}


def markdown(result: dict, command: str) -> str:
    limit = result['limit_s']
    lines = [results.header(result, 'Stopping every node and `session`', command),
             f'Each subject started {result["stops_per_subject"]} times and sent SIGINT or '
             f'SIGTERM (in turn) at a random moment; conditions in `bench_stop --help`.\n',
             f'| subject | stops | ended within {limit:g} s | SIGKILL needed | worst [s] | '
             'median [s] | p95 [s] | exit codes | orphans |', '|' + '---|' * 9]
    for subject, s in result['summary'].items():
        def fmt(x):
            return '-' if x is None else f'{x:.2f}'
        lines.append(f'| {subject} | {s["stops"]} | {s["within_limit"]} of {s["stops"]} | '
                     f'{s["killed"]} | {fmt(s["worst_s"])} | {fmt(s["median_s"])} | '
                     f'{fmt(s["p95_s"])} | '
                     + ', '.join(f'{code}: {n}' for code, n in sorted(s['exit_codes'].items()))
                     + f' | {s["orphans"]} |')
    odd = [r for r in result['stops'] if 'log_tail' in r]
    if odd:
        lines += ['', '## Stops that were killed, slow, not clean, or ended before the signal', '']
        for r in odd:
            lines.append(f'* {r["subject"]}, {r["device"]}/{r["moment"]}'
                         + (f' (reached {r["reached"]})' if r['reached'] else '')
                         + f', {r["signal"]} {r["after_start_s"]:.2f} s after start: '
                         + ('ended before the signal' if r['ended_before_signal']
                            else f'{r["stop_s"]:.2f} s') + f', exit {r["exit_code"]}'
                         + (', KILLED' if r['killed'] else '')
                         + (f', {r["orphans"]} orphans' if r['orphans'] else ''))
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog='bench_stop', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--subjects', nargs='+', default=list(SUBJECTS), choices=SUBJECTS)
    parser.add_argument('--stops', type=int, default=50, help='stops per subject')
    parser.add_argument('--limit', type=float, default=2.0,
                        help='seconds within which a stop counts as prompt')
    parser.add_argument('--kill-after', type=float, default=10.0,
                        help='seconds after the signal before the subject is killed')
    parser.add_argument('--start-window', type=float, default=4.0,
                        help='`starting`: the signal comes within this many s of the start')
    parser.add_argument('--transition-timeout', type=float, default=10.0,
                        help='longest wait for a lifecycle transition')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--out', type=output_folder, default='out/bench_stop')
    parser.add_argument('--domain', type=int, default=60 + os.getpid() % 20,
                        help='ROS_DOMAIN_ID of the benchmark graph')
    parser.add_argument('--ports', type=int, nargs=3, default=[25201, 25202, 25203],
                        help='emulator ports on 127.0.0.1 of the graph around the subjects')
    parser.add_argument('--session-ports', type=int, nargs=3, default=[25211, 25212, 25213],
                        help='emulator ports of the sessions `session` starts')
    args = parser.parse_args(argv)
    interrupt_on_sigterm()      # its finally blocks stop the processes it started
    if args.stops < 1 or args.limit <= 0 or args.kill_after <= args.limit:
        parser.error('--stops must be >= 1 and 0 < --limit < --kill-after')
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env = {**os.environ, 'PYTHONUNBUFFERED': '1'}
    rng = random.Random(args.seed)
    result = {'provenance': results.provenance(), 'stops_per_subject': args.stops,
              'limit_s': args.limit, 'kill_after_s': args.kill_after,
              'start_window_s': args.start_window, 'seed': args.seed, 'stops': [],
              'summary': {}}
    command = 'bench_stop ' + ' '.join(sys.argv[1:] if argv is None else argv)
    graph = GraphProbe('bench_stop')
    try:
        with tempfile.TemporaryDirectory(prefix='bench_stop_') as tmp:
            for subject in args.subjects:
                rows = run_subject(subject, args, env, graph, Path(tmp) / subject, rng)
                result['stops'] += rows
                result['summary'][subject] = summary(rows, args.limit)
                # Written after every subject: an hour's run interrupted keeps what it measured.
                json_path, md_path = results.write(args.out, 'bench_stop', result,
                                                   lambda r: markdown(r, command))
    finally:
        graph.close()
    print(md_path.read_text())
    print(f'wrote {json_path} and {md_path}')


if __name__ == '__main__':
    main()
