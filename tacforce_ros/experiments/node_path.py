"""The same calibration session and closed-loop run through the real node graph (`session` tool:
sim_world + device emulators + drivers + recorder / estimator / controller over DDS), compared
with the direct (in-process) path on the same scene and seed.

Agreement is judged within stated tolerances (AGREEMENT_N, reasons in AGREEMENT_REASON).
"""
from __future__ import annotations

import os
import socket
import subprocess
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.bringup.processes import executable, read_exit_codes, run_to_end
from tacforce_ros.control.force_controller import MODE_HOLD, MODE_SAFE
from tacforce_ros.estimation.metrics import error_stats
from tacforce_ros.estimation.model_set import load_model_set
from tacforce_ros.rig import RATE_HZ
from tacforce_ros.experiments.closed_loop import (METRIC_WINDOW, ClosedLoopTrace, run_closed_loop,
                                                  trace_metrics)
from tacforce_ros.bringup.session_plan import SESSION_SCENE_ENDED

if TYPE_CHECKING:
    from tacforce_ros.experiments.grasp import GraspTrace
    from tacforce_ros.hand.description import HandDescription
    from tacforce_ros.hand.kinematics import HandKinematics

AGREEMENT_N = {'calibration_e_hat': 0.05, 'closed_loop_e_tilde': 0.08,
               'closed_loop_e_track': 0.03, 'grasp_finger_e_tilde': 0.08}
AGREEMENT_REASON = (
    'Calibration e_hat: the node graph moves the streams through sockets and DDS, whose '
    'delivery jitter of a few ms shifts tactile, F/T and joint streams against each other; at '
    'the sessions\' force slopes of a few N/s that is a few hundredths of a newton. Closed '
    'loop: same scene, seed, model, gains and sequence; in lockstep (sim_world waits for the '
    'controller, the estimate and the joint stream) the graph\'s controller acts on joints and '
    'estimates up to one of their periods plus a few ms old, and its torque lands up to a '
    'controller period later, by how the processes are scheduled (the direct path: always one '
    'period later); it tares on its first frames rather than the last of a 2 s hold, and starts '
    'when the command player does; the tip then meets the plate a little differently. Measured '
    'with bench_graph (3 runs, seeds 0-2): e~ within 0.011 N and e_track within 0.001 N of the '
    'direct run, so 0.08 N on e~ and 0.03 N on e_track leave room for a loaded machine. On the '
    'magnetic skin the loop\'s resting contact, and its e~, follow the command\'s delay (direct: '
    '0.28 N at 0 ms, 0.19 N at 10 ms, 0.14 N at 20 ms); bench_graph --skin magnetic: e~ within '
    '0.006-0.077 N, at the edge of the tolerance.')
CALIBRATION_SECONDS = 40.0     # simulated seconds of the node-graph calibration session
# Simulated seconds a closed-loop scene runs before the sequence can start: the command player
# waits until the controller and the recorder listen (discovery), while the finger holds.
SEQUENCE_START_MARGIN_S = 10.0
START_MARGIN_S = 40.0          # wall seconds for the nodes to start and the recorder to open
# Sessions run in lockstep (simulated time waits for the controller, the estimate and the joint
# stream in closed loop, for the recorder in calibration) at up to real time; a session slower
# than this is given up as unusable, not waited for forever.
SLOWEST_REAL_TIME_FACTOR = 0.1
TACTILE_PERIOD_S = 0.01        # the estimator's tare counts 100 Hz tactile frames
MIN_ZERO_SAMPLES = 10          # F/T readings (1 kHz) averaged at least to zero the sensor


class NodePathUnavailable(RuntimeError):
    """The node graph could not run here; the message says why (reported, never faked)."""


def _free_ports(count: int) -> list[int]:
    """Ports on 127.0.0.1 free for both TCP and UDP right now (the emulators bind them)."""
    ports: list[int] = []
    while len(ports) < count:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp:
            tcp.bind(('127.0.0.1', 0))
            port = tcp.getsockname()[1]
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
                try:
                    udp.bind(('127.0.0.1', port))
                except OSError:
                    continue
        if port not in ports:
            ports.append(port)
    return ports


def run_session(mode: str, scene: str, plate: str, out: Path, sim_duration: float,
                model_config: Path | None = None, seed: int | None = None,
                lockstep: bool = True, crash: tuple[str, float, float] | None = None,
                compose: bool = False, sequence: str | None = None,
                extra: tuple[str, ...] = ()) -> Path:
    """Run the `session` tool once until its scene has run `sim_duration` simulated seconds
    (seed None: the scene's own; lockstep False: free-running at real time; crash: the
    session's fault drill, node, at and down wall seconds; compose: the nodes in one process;
    sequence: the closed loop's force command sequence, None: the command player's default;
    extra: more of the tool's arguments, e.g. a grasp's); return the bag folder it recorded.
    Its output is kept in `out`/session.log."""
    try:
        session_exe = executable('session')
    except FileNotFoundError as error:
        raise NodePathUnavailable(str(error)) from None
    out.mkdir(parents=True, exist_ok=True)
    wall_limit = sim_duration / SLOWEST_REAL_TIME_FACTOR + START_MARGIN_S
    command = [str(session_exe), mode, '--scene', scene,   # as a user would run it
               '--array', 'index_tip', '--plate', plate, '--out', str(out),
               '--sim-duration', f'{sim_duration:g}', '--duration', f'{wall_limit:g}',
               '--lockstep' if lockstep else '--no-lockstep', '--ports', *map(str, _free_ports(3))]
    if model_config is not None:
        command += ['--model', str(model_config)]
    if seed is not None:
        command += ['--seed', str(seed)]
    if crash is not None:
        command += ['--crash', crash[0], f'{crash[1]:g}', f'{crash[2]:g}']
    if compose:
        command.append('--compose')
    if sequence is not None:
        command += ['--sequence', sequence]
    command += list(extra)
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    # A domain of our own, so DDS traffic of other processes on this host stays out.
    env['ROS_DOMAIN_ID'] = str(env.get('TACFORCE_REPRODUCE_DOMAIN', 40 + os.getpid() % 50))
    try:
        done = run_to_end(command, timeout=wall_limit + 90.0, env=env)
    except subprocess.TimeoutExpired as exc:
        raise NodePathUnavailable(f'session {mode} did not stop within {wall_limit + 90:g} s') \
            from exc
    (out / 'session.log').write_text(done.stdout + done.stderr)
    early = [line for line in done.stderr.splitlines() if 'exited early' in line]
    if SESSION_SCENE_ENDED not in done.stdout and early:
        raise NodePathUnavailable(f'session {mode}: {early[0].removeprefix("session: ")} '
                                  f'(log: {out / "session.log"})')
    if SESSION_SCENE_ENDED not in done.stdout:
        raise NodePathUnavailable(
            f'session {mode}: {sim_duration:g} s simulated did not run within {wall_limit:g} s '
            f'(slower than {SLOWEST_REAL_TIME_FACTOR:g}x real time; exit code '
            f'{done.returncode}, log: {out / "session.log"}): {done.stderr.strip()[-300:]}')
    bags = sorted(p for p in out.iterdir() if p.is_dir() and (p / 'metadata.yaml').is_file())
    if not bags:
        raise NodePathUnavailable(f'session {mode} exited {done.returncode} and recorded no bag '
                                  f'(log: {out / "session.log"}): {done.stderr.strip()[-300:]}')
    return bags[-1]


def session_exit_codes(session_dir: Path) -> dict[str, int]:
    """How each node of a session run by run_session ended (its log's last status line; 0:
    cleanly, negative: killed by that signal, e.g. -9 when it did not stop within the session's
    grace); empty when the log has none."""
    log = session_dir / 'session.log'
    for line in reversed(log.read_text(errors='replace').splitlines() if log.is_file() else []):
        codes = read_exit_codes(line)
        if codes is not None:
            return codes
    return {}


def closed_loop_against_direct(hand: HandDescription, kinematics: HandKinematics, scene: str,
                               plate: str, seed: int, model_config: Path, sequence, out: Path,
                               controller, tare_frames: int, control_rate: float = RATE_HZ,
                               lockstep: bool = True, compose: bool = False
                               ) -> tuple[dict, ClosedLoopTrace, ClosedLoopTrace, Path]:
    """The closed loop of `sequence` on `scene` directly (in-process) and through the node
    graph (`session`, into `out`), same seed, models and controller configuration: returns
    compare_closed_loop's result, the node and direct traces, and the node run's bag."""
    direct = run_closed_loop(hand, kinematics, scene, seed, controller, sequence,
                             load_model_set(model_config, hand), control_rate=control_rate,
                             tare_frames=tare_frames)
    bag = run_session('closed_loop', scene, plate, out,
                      closed_loop_session_seconds(sequence.duration), model_config, seed=seed,
                      lockstep=lockstep, compose=compose, sequence=sequence.source)
    trace, offset = node_trace(bag, sequence, tare_frames)
    compared = compare_closed_loop(trace, direct, offset)
    compared['exit_codes'] = session_exit_codes(out)
    return compared, trace, direct, bag


def bag_check(bag: Path) -> dict:
    """What ROS tools see of a node run's bag: its files, and its messages per topic as its
    metadata, rosbags and Foxglove's mcap reader count them (they must agree)."""
    from tacforce_ros import bagio
    counts = bagio.reader_counts(bag)
    return {'files': len(bagio.bag_files(bag)), 'messages': sum(counts['rosbags'].values()),
            'counts': counts,
            'agree': counts['metadata'] == counts['rosbags'] == counts['mcap']}


def closed_loop_session_seconds(sequence_seconds: float) -> float:
    """Simulated seconds a closed-loop session runs to play a sequence of this length."""
    return sequence_seconds + SEQUENCE_START_MARGIN_S


def _seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def compare_calibration(bag: Path, hand: HandDescription, kinematics: HandKinematics,
                        scene: str, seed: int, model_path: str, static_force: float) -> dict:
    """e_hat of the trained model on the node-recorded session and on the same window simulated
    directly (same scene, seed and simulated-time span)."""
    from tacforce_ros import bagio, topics
    from tacforce_ros.estimation.bag_dataset import dataset_from_bag
    from tacforce_ros.estimation.model_io import load_model
    from tacforce_ros.experiments.calibration_data import simulate_calibration
    bundle = load_model(model_path, hand.array('index_tip'))
    # Frames stamped 0 were stamped before the first /clock: they say nothing about the window.
    tactile_time = [t for t in (_seconds(m.header.stamp) for _, _, m in
                                bagio.read_messages(bag, [topics.TOPIC_TACTILE])) if t > 0.0]
    if not tactile_time:
        raise NodePathUnavailable(f'{bag}: no tactile frame stamped in simulated time')
    start, stop = min(tactile_time), max(tactile_time)
    node, dropped = dataset_from_bag(bag, hand, kinematics)
    direct = simulate_calibration(hand, kinematics, scene, seed, stop, start=start)
    result = {'bag': str(bag), 'window_s': [start, stop], 'dropped_messages': dropped}
    for name, data in (('node', node), ('direct', direct)):
        X, F, _ = data.without_offsets(force_threshold=static_force)
        stats = error_stats(F, bundle.predict(X, tare=np.zeros_like(bundle.x_offset)))
        result[name] = {'samples': int(len(F)), 'e_hat_mean': stats.e_hat_mean,
                        'e_r_mean': stats.e_r_mean}
    result['difference_n'] = abs(result['node']['e_hat_mean'] - result['direct']['e_hat_mean'])
    result['tolerance_n'] = AGREEMENT_N['calibration_e_hat']
    result['agree'] = result['difference_n'] <= result['tolerance_n']
    return result


def node_trace(bag: Path, sequence, tare_frames: int) -> tuple[ClosedLoopTrace, float]:
    """The node run as a trace on the sequence's clock, and where that clock starts (simulated
    time of the command player's first f_d).

    Everything comes from the bag as the graph saw it: the controller's ticks
    (/force_controller/state: f_d, and f_hat where the estimate was fresh, both in {F}) and the
    F/T reading, zeroed on its `tare_frames` tactile periods before the controller engaged
    (its first tick in open or closed loop: a `safe` tick before it is the start hold's
    watchdog), while the finger still held its start pose clear of the
    plate: the direct path zeroes it the same way at the end of its hold. (Not before the first
    command: the player may start before the recorder has its first F/T reading.)
    """
    from tacforce_ros import bagio, topics
    states, desired, wrench = [], [], []
    for topic, _, msg in bagio.read_messages(bag, [topics.TOPIC_CONTROLLER_STATE,
                                                   topics.TOPIC_DESIRED, topics.TOPIC_WRENCH]):
        t = _seconds(msg.header.stamp)
        if topic == topics.TOPIC_DESIRED:
            desired.append(t)
        elif topic == topics.TOPIC_WRENCH:
            f = msg.wrench.force
            wrench.append((t, f.x, f.y, f.z))
        else:
            fresh = msg.estimate_fresh
            states.append((t, msg.mode not in (MODE_HOLD, MODE_SAFE), *_xyz(msg.desired_force),
                           *(_xyz(msg.estimated_force) if fresh else (np.nan,) * 3)))
    if not desired or len(states) < 2 or len(wrench) < 2:
        raise NodePathUnavailable(f'{bag}: {len(desired)} commands, {len(states)} controller '
                                  f'ticks, {len(wrench)} F/T samples: not a closed-loop run')
    start = min(desired)
    ticks = np.asarray(sorted(states), np.float64)
    engaged_ticks = ticks[ticks[:, 1] > 0.0, 0]
    engaged = engaged_ticks[0] if engaged_ticks.size else start
    ticks = np.delete(ticks, 1, axis=1)
    ft = np.asarray(sorted(wrench), np.float64)
    resting = (ft[:, 0] < engaged) & (ft[:, 0] >= engaged - tare_frames * TACTILE_PERIOD_S)
    if resting.sum() < MIN_ZERO_SAMPLES:
        raise NodePathUnavailable(f'{bag}: {resting.sum()} F/T readings before the controller '
                                  f'engaged; {MIN_ZERO_SAMPLES} needed to zero it')
    zero = ft[resting, 1:].mean(axis=0)
    t = ticks[:, 0] - start
    end = sequence.duration
    if t[-1] < min(end, METRIC_WINDOW[1]) - 1.0:
        raise NodePathUnavailable(f'{bag}: the run stops at {t[-1]:.1f} s of the {end:g} s '
                                  'sequence (too slow a simulation for the session time?)')
    keep = (t >= 0.0) & (t <= end)
    f_tilde = np.column_stack([np.interp(ticks[keep, 0], ft[:, 0], ft[:, k]) - zero[k - 1]
                               for k in (1, 2, 3)])
    return ClosedLoopTrace(t=t[keep], f_d=ticks[keep, 1:4], f_hat=ticks[keep, 4:7],
                           f_tilde=f_tilde), start


def _xyz(vector) -> tuple[float, float, float]:
    return vector.x, vector.y, vector.z


def compare_closed_loop(node: ClosedLoopTrace, direct: ClosedLoopTrace, offset: float) -> dict:
    """Table III metrics of both runs, and whether e~ and e_track agree within AGREEMENT_N."""
    node_m, direct_m = trace_metrics([node]), trace_metrics([direct])
    difference = abs(node_m['e_tilde_mean'] - direct_m['e_tilde_mean'])
    result = {'clock_offset_s': offset, 'node': node_m, 'direct': direct_m,
              'difference_n': difference, 'tolerance_n': AGREEMENT_N['closed_loop_e_tilde'],
              'agree': difference <= AGREEMENT_N['closed_loop_e_tilde']}
    if node_m['e_track_mean'] is not None and direct_m['e_track_mean'] is not None:
        track = abs(node_m['e_track_mean'] - direct_m['e_track_mean'])
        result.update(e_track_difference_n=track,
                      e_track_tolerance_n=AGREEMENT_N['closed_loop_e_track'],
                      agree=result['agree'] and track <= AGREEMENT_N['closed_loop_e_track'])
    return result


# --- a grasp ---------------------------------------------------------------------------------

def grasp_node_trace(bag: Path, hand: HandDescription, kinematics: HandKinematics, scene: str,
                     grip: float) -> GraspTrace:
    """A grasp session's run as experiments/grasp.py's GraspTrace, from its bag: each
    fingertip's f_d and f_hat from grasp_controller's ticks (/grasp_controller/state, base frame;
    f_hat where fresh), its contact force from the simulator's truth (/sim/contact_force in
    the fingertip's {S0}: the newest frame at each tick, turned into the base frame at the
    tick's joint angles), d_i from the tick's joint angles (control.grasp.grip_directions),
    the object's position (/sim/object_pose) and what the simulator judges of it: held by the
    fixture before the scene's hand-over, dropped once DROP_DISTANCE below where it was then.
    t = 0 is the goal's first tick. The grip asked is the goal's (a raise on slip is in the
    action's feedback, not in the bag)."""
    from tacforce_ros import bagio, topics
    from tacforce_ros.control.grasp import grip_directions
    from tacforce_ros.experiments.grasp import GraspTrace
    from tacforce_ros.hand.pinch import pad
    from tacforce_ros.sim import load_scene
    from tacforce_ros.sim.grasp import DROP_DISTANCE
    spec = load_scene(scene)
    fingers = tuple(spec.grasp['fingers'])
    frames = {hand.array(f'{f}_tip').frame_id: f for f in fingers}
    unprefixed = lambda frame_id: frame_id.rsplit('/', 1)[-1]     # noqa: E731 (frame_prefix)
    ticks: dict[float, dict] = {}
    truth: dict[str, list] = {f: [] for f in fingers}
    pose = []
    for topic, _, msg in bagio.read_messages(bag, [topics.TOPIC_GRASP_STATE,
                                                   topics.TOPIC_SIM_CONTACT,
                                                   topics.TOPIC_SIM_OBJECT]):
        t = _seconds(msg.header.stamp)
        if topic == topics.TOPIC_GRASP_STATE:
            ticks.setdefault(t, {})[msg.finger] = msg
        elif topic == topics.TOPIC_SIM_CONTACT:
            if unprefixed(msg.header.frame_id) in frames:
                truth[frames[unprefixed(msg.header.frame_id)]].append(
                    (t, *_xyz(msg.wrench.force)))
        else:
            p = msg.pose.position
            pose.append((t, p.x, p.y, p.z))
    stamps = sorted(t for t, states in ticks.items() if set(states) == set(fingers))
    if len(stamps) < 2 or not pose or not all(truth.values()):
        raise NodePathUnavailable(f'{bag}: {len(stamps)} grasp ticks, {len(pose)} object '
                                  f'poses, truth {[len(v) for v in truth.values()]}: not a '
                                  'grasp run')
    n, count = len(fingers), len(stamps)
    f_d, f_hat, f_true, directions = (np.full((count, n, 3), np.nan) for _ in range(4))
    truth_arrays = {f: np.asarray(sorted(v)) for f, v in truth.items()}
    for k, t in enumerate(stamps):
        q16 = np.zeros(16)
        for f in fingers:
            q16[kinematics.finger_joints(f)] = ticks[t][f].q
        d = grip_directions(lambda q, f: pad(hand, kinematics, q, f)[0], fingers, q16)
        for i, f in enumerate(fingers):
            state = ticks[t][f]
            f_d[k, i] = _xyz(state.desired_force)
            if state.estimate_fresh:
                f_hat[k, i] = _xyz(state.estimated_force)
            rows = truth_arrays[f]
            newest = max(int(np.searchsorted(rows[:, 0], t, side='right')) - 1, 0)
            rotation = kinematics.rotation_between(q16, hand.array(f'{f}_tip').frame_id,
                                                   hand.base_frame)
            f_true[k, i] = np.asarray(rotation) @ rows[newest, 1:]
            directions[k, i] = d[f]
    poses = np.asarray(sorted(pose))
    position = np.column_stack([np.interp(stamps, poses[:, 0], poses[:, c]) for c in (1, 2, 3)])
    scene_t = np.asarray(stamps)
    hand_over = float(spec.grasp['hand_over'])
    held = scene_t < hand_over
    # Dropped as the simulator judges it: once let go, DROP_DISTANCE below where the fixture let
    # go of it, on every pose the simulator published (also after the last tick).
    down = np.asarray(spec.grasp['gravity'], np.float64)
    down /= np.linalg.norm(down)
    handed_at = np.array([np.interp(hand_over, poses[:, 0], poses[:, c]) for c in (1, 2, 3)])
    after = poses[:, 0] >= hand_over
    fell = after & ((poses[:, 1:] - handed_at) @ down > DROP_DISTANCE)
    first_fall = poses[fell.argmax(), 0] if fell.any() else np.inf
    dropped = scene_t >= first_fall
    if fell.any() and not dropped.any():
        dropped[-1] = True          # it fell after the last tick
    return GraspTrace(fingers=fingers, t=scene_t - scene_t[0], f_d=f_d, f_hat=f_hat,
                      f_true=f_true, directions=directions, grip=np.full(count, float(grip)),
                      object_position=position, held_by_fixture=held, dropped=dropped,
                      phase=np.full(count, ''), command=float(grip))


def grasp_against_direct(hand: HandDescription, kinematics: HandKinematics, scene: str,
                         seed: int, model_config: Path, grip: float, out: Path, configs: dict,
                         tare_frames: int) -> tuple[dict, GraspTrace, GraspTrace, Path]:
    """One grasp of `scene` at `grip` N in-process (experiments/grasp.py) and through the node
    graph (`session grasp`, into `out`), same seed and models (the shipped gains: `configs`,
    each fingertip's law as the grasp_controller node builds it): returns the comparison, the
    node and direct traces, and the node run's bag."""
    from tacforce_ros.experiments.grasp import grasp_metrics, run_grasp
    from tacforce_ros.sim import load_scene
    spec = load_scene(scene)
    direct = run_grasp(hand, scene, seed, configs, load_model_set(model_config, hand), grip,
                       tare_frames=tare_frames)
    obj = spec.grasp_object.name
    bag = run_session('grasp', scene, obj, out, spec.duration, model_config, seed=seed,
                      extra=('--object', obj, '--grip', f'{grip:g}'))
    trace = grasp_node_trace(bag, hand, kinematics, scene, grip)
    from tacforce_ros.bringup.processes import unclean_exits
    node_m, direct_m = grasp_metrics(trace), grasp_metrics(direct)
    difference = abs(node_m['finger_error_mean_n'] - direct_m['finger_error_mean_n'])
    tolerance = AGREEMENT_N['grasp_finger_e_tilde']
    codes = session_exit_codes(out)
    compared = {'object': obj, 'grip_n': grip, 'seed': seed, 'node': node_m, 'direct': direct_m,
                'difference_n': difference, 'tolerance_n': tolerance,
                'agree': bool(difference <= tolerance and not node_m['dropped']
                              and not direct_m['dropped'] and codes
                              and not unclean_exits(codes)),
                'exit_codes': codes}
    return compared, trace, direct, bag
