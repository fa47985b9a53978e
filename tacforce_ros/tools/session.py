"""session: run a calibration, closed-loop or grasp session without `ros2 launch`.

Starts the same executables with the same parameter files and argument-derived overrides as
launch/<mode>.launch.py (both read tacforce_ros.bringup.session_plan), waits for Ctrl-C,
`--duration` seconds (wall time), the end of the scene (`--sim-duration` simulated seconds:
sim_world then logs session_plan.SCENE_DONE_MARKER) or for a node to exit (a simulated grasp's
grasp_client ending cleanly, with its goal's result, is the session's end), then stops every node
cleanly: SIGINT, wait `--grace` s, then kill. Prints where the bag is. Exit code 0 when every
node stopped cleanly, 1 otherwise (the log of each node is under <out>/logs/).

In simulation, simulated time waits for the nodes that close the loop (closed loop: the
controller, the estimate and the joint stream; calibration: the recorder; sim_world's
lockstep); `--no-lockstep` runs it free at `--real-time-factor`.

`--compose` runs every node but the simulator in one tacforce_container process (one executor);
at the end the CPU seconds of each process are printed either way.

`--crash NODE AT DOWN` is a fault drill: NODE is killed (SIGKILL, as a crash) AT wall seconds
after the session started and started again, with the same arguments, DOWN seconds later (as
launch's respawn would); its log goes on in the same file. The session's exit code then ignores
the killed process.

    session calibration --scene calibration_index_tip_flat --array index_tip --plate flat \\
        --out bags --duration 120
    session closed_loop --scene closed_loop_spherical --model config/models/default.yaml
    session grasp --object tennis_ball --grip 2 --sim-duration 11
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from tacforce_ros.bringup.processes import (cpu_report, cpu_seconds, exit_codes_report,
                                           first_exited, start_nodes, stop_nodes,
                                           unclean_exits)
from tacforce_ros.bringup.session_plan import (CAN_PORT, MODES, NETFT_PORT, SCENE_DONE_MARKER,
                                             SESSION_SCENE_ENDED, XELA_PORT, NodeLaunch,
                                             PlanError, SessionArgs, campaign_session, plan)
from tacforce_ros.paths import output_folder

POLL_S = 0.1


class SceneLog:
    """Watches sim_world's log for the end of its scene, as launch's OnProcessIO would."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._read = 0
        self._tail = b''

    def done(self) -> bool:
        try:
            with open(self.path, 'rb') as log:
                log.seek(self._read)
                text = log.read()
        except FileNotFoundError:
            return False
        self._read += len(text)
        # The marker may straddle two reads: keep the end of the previous one.
        self._tail = (self._tail + text)[-4096:]
        return SCENE_DONE_MARKER.encode() in self._tail


@dataclass(frozen=True)
class Crash:
    """A fault drill: `node` is killed `at_s` wall seconds into the session and restarted
    `down_s` seconds later."""

    node: str
    at_s: float
    down_s: float


class CrashDrill:
    """Carries out a Crash on the running session's processes."""

    def __init__(self, crash: Crash, nodes: list[NodeLaunch], log_dir: Path) -> None:
        launch = next((n for n in nodes if n.executable == crash.node), None)
        if launch is None:
            if any(p.executable == crash.node for n in nodes for p in n.parts):
                raise PlanError(f'--crash: {crash.node!r} shares a process with other nodes '
                                '(--compose): a crash drill needs it in a process of its own')
            raise PlanError(f'--crash: {crash.node!r} is not a node of this session '
                            f'({", ".join(n.executable for n in nodes)})')
        self.crash, self.launch, self.log_dir = crash, launch, log_dir
        self.down = False
        self.done = False

    def step(self, elapsed: float, procs: list[tuple[str, subprocess.Popen]]) -> None:
        """Kill or restart when due (procs is updated in place)."""
        if self.done:
            return
        index = next(k for k, (name, _) in enumerate(procs) if name == self.crash.node)
        if not self.down and elapsed >= self.crash.at_s:
            procs[index][1].kill()
            procs[index][1].wait(timeout=5.0)
            self.down = True
            print(f'session: {self.crash.node} killed at {elapsed:.1f} s (fault drill)',
                  flush=True)
        elif self.down and elapsed >= self.crash.at_s + self.crash.down_s:
            procs[index] = start_nodes([self.launch], self.log_dir, log_mode='a')[0]
            self.done = True
            print(f'session: {self.crash.node} restarted at {elapsed:.1f} s (fault drill)',
                  flush=True)

    def is_down(self, name: str) -> bool:
        return self.down and not self.done and name == self.crash.node


def run(args: SessionArgs, duration: float | None, grace: float,
        crash: Crash | None = None) -> int:
    try:
        if args.campaign:
            args = campaign_session(args)
            print(f'session: campaign {args.campaign}: {args.array} on the {args.plate} plate',
                  flush=True)
        nodes = plan(args)
        log_dir = Path(args.out) / 'logs'
        drill = CrashDrill(crash, nodes, log_dir) if crash is not None else None
    except PlanError as exc:
        print(f'session: {exc}', file=sys.stderr)
        return 2
    stop = {'requested': False}
    previous = {sig: signal.signal(sig, lambda *_: stop.update(requested=True))
                for sig in (signal.SIGINT, signal.SIGTERM)}
    procs = start_nodes(nodes, log_dir)
    finishing = {n.executable for n in nodes if n.finishes}
    print(f'session {args.mode}: started {", ".join(name for name, _ in procs)} '
          f'(logs in {log_dir})', flush=True)
    started = time.monotonic()
    exited_early = None
    scene_log = (SceneLog(log_dir / 'sim_world.log') if args.sim and args.sim_duration > 0
                 else None)
    try:
        while not stop['requested'] and exited_early is None:
            if duration is not None and time.monotonic() - started >= duration:
                break
            if scene_log is not None and scene_log.done():
                print(f'{SESSION_SCENE_ENDED} after {args.sim_duration:g} s simulated',
                      flush=True)
                break
            if drill is not None:
                drill.step(time.monotonic() - started, procs)
            exited = first_exited([(name, proc) for name, proc in procs
                                   if not (drill is not None and drill.is_down(name))])
            exited_early = exited[0] if exited else None
            if exited_early in finishing and exited[1] == 0:
                print(f'session: {exited_early} finished (see {log_dir}/{exited_early}.log)',
                      flush=True)
                exited_early = None
                break
            if exited_early:
                print(f'session: {exited_early} exited early (code {exited[1]}); see '
                      f'{log_dir}/{exited_early}.log', file=sys.stderr)
                break
            time.sleep(POLL_S)
    finally:
        cpu = {name: cpu_seconds(proc.pid) for name, proc in procs}
        print(cpu_report(cpu), flush=True)
        codes = stop_nodes(procs, grace)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    out = Path(args.out)
    bags = sorted(p for p in out.iterdir() if p.is_dir() and p.name != 'logs')
    print(f'session {args.mode}: stopped after {time.monotonic() - started:.1f} s; '
          + exit_codes_report(codes))
    print('bags:' + ''.join(f'\n  {p.resolve()}' for p in bags) if bags else
          f'no bag in {out.resolve()}')
    return 0 if exited_early is None and not unclean_exits(codes) else 1


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog='session', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('mode', choices=MODES)
    parser.add_argument('--hardware', action='store_true',
                        help='use the real devices (default: sim_world and its emulators)')
    parser.add_argument('--hand-side', default='right', help='hand description side')
    parser.add_argument('--array', default='index_tip',
                        help='array pressed (calibration) or fingertip that closes the loop '
                        '(index_tip, middle_tip, ring_tip or thumb_tip)')
    parser.add_argument('--plate', default='spherical', help='push-plate or object')
    parser.add_argument('--scene', default='', help='sim scene (default from mode/array/plate)')
    parser.add_argument('--model', default='',
                        help='estimator models YAML (closed_loop, grasp)')
    parser.add_argument('--object', default='golf_ball',
                        help='grasp: the object held (simulation: scene grasp_<object>)')
    parser.add_argument('--grip', type=float, default=1.0, help='grasp: grip force (N)')
    parser.add_argument('--hold-time', type=float, default=0.0,
                        help='grasp: hold this long, then release (s); 0: until the end')
    parser.add_argument('--sequence', default='',
                        help='force command sequence (closed_loop): a name in config/commands/ '
                        'or a YAML path (default: command_player.yaml\'s, paper_70s)')
    parser.add_argument('--out', type=output_folder, default='bags',
                        help='folder for bags and node logs')
    parser.add_argument('--campaign', default='',
                        help='calibration: record the next session this campaign folder has '
                        'due (its array, plate and folder; in simulation its length and seed)')
    parser.add_argument('--real-time-factor', type=float, default=1.0,
                        help='simulated seconds per wall second (sim only; with lockstep the '
                        'most it runs at)')
    parser.add_argument('--lockstep', action=argparse.BooleanOptionalAction, default=True,
                        help='sim only: simulated time waits for the nodes closing the loop '
                        '(default); --no-lockstep: free-running')
    parser.add_argument('--sim-duration', type=float, default=0.0,
                        help='sim only: end the session after this many simulated seconds '
                        '(default 0: until Ctrl-C or --duration)')
    parser.add_argument('--seed', type=int, default=-1,
                        help='simulator seed (sim only; default -1: the scene\'s own)')
    parser.add_argument('--duration', type=float, default=None,
                        help='stop after this many wall seconds (default: until Ctrl-C)')
    parser.add_argument('--grace', type=float, default=10.0,
                        help='seconds the nodes get to stop after SIGINT before being killed')
    parser.add_argument('--compose', action='store_true',
                        help='the nodes (all but the simulator) in one tacforce_container process')
    parser.add_argument('--namespace', default='',
                        help='every node in this ROS namespace (e.g. /left: /left/tactile/raw, '
                        'and in simulation /left/clock); default: the root namespace')
    parser.add_argument('--frame-prefix', default='',
                        help='put in front of every frame id the nodes publish (e.g. left/: '
                        'left/uskin_index_tip), as robot_state_publisher\'s frame_prefix')
    parser.add_argument('--autostart', action=argparse.BooleanOptionalAction, default=True,
                        help='the drivers configure and activate themselves (default); '
                        '--no-autostart: they start unconfigured, for ros2 lifecycle set')
    parser.add_argument('--crash', nargs=3, metavar=('NODE', 'AT', 'DOWN'),
                        help='fault drill: kill NODE AT wall seconds into the session, start it '
                        'again DOWN seconds later')
    parser.add_argument('--ports', type=int, nargs=3, default=[XELA_PORT, NETFT_PORT, CAN_PORT],
                        metavar=('XELA', 'NETFT', 'CAN'),
                        help='emulator ports on 127.0.0.1 (sim only)')
    a = parser.parse_args(argv)
    if a.duration is not None and a.duration <= 0:
        parser.error('--duration must be positive')
    crash = None
    if a.crash:
        try:
            crash = Crash(a.crash[0], float(a.crash[1]), float(a.crash[2]))
        except ValueError:
            parser.error(f'--crash: AT and DOWN must be seconds, got {a.crash[1:]}')
        if crash.at_s < 0 or crash.down_s < 0:
            parser.error('--crash: AT and DOWN must be >= 0')
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    sys.exit(run(SessionArgs(mode=a.mode, sim=not a.hardware, hand_side=a.hand_side,
                             array=a.array, plate=a.plate, scene=a.scene,
                             grasp_object=a.object, grip=a.grip, hold_time=a.hold_time,
                             model_config=a.model, sequence=a.sequence, out=str(a.out),
                             real_time_factor=a.real_time_factor, lockstep=a.lockstep,
                             sim_duration=a.sim_duration, seed=a.seed, compose=a.compose,
                             autostart=a.autostart, namespace=a.namespace,
                             frame_prefix=a.frame_prefix, campaign=a.campaign,
                             xela_port=a.ports[0],
                             netft_port=a.ports[1], can_port=a.ports[2]),
                 a.duration, a.grace, crash))


if __name__ == '__main__':
    main()
