"""The same calibration session and closed-loop run through the real node graph (`session` tool:
sim_world + device emulators + drivers + recorder / estimator / controller over DDS), compared
with the direct (in-process) path on the same scene and seed.

Agreement is judged within stated tolerances (AGREEMENT_N): the node graph moves every stream
through sockets and DDS, whose delivery jitter shifts the tactile, F/T and joint streams by a few
milliseconds against each other (and the recorder and controller see them at those times), and
the closed-loop controller runs on whatever arrived last; a 10 ms misalignment at the force
slopes of these sessions (a few N/s) is a few hundredths of a newton.
"""
from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tacforce_ros.estimation.metrics import error_stats
from tacforce_ros.experiments.closed_loop import ClosedLoopTrace, trace_metrics

if TYPE_CHECKING:
    from tacforce_ros.hand.description import HandDescription
    from tacforce_ros.hand.kinematics import HandKinematics

AGREEMENT_N = {'calibration_e_hat': 0.05, 'closed_loop_e_tilde': 0.05}
CALIBRATION_SECONDS = 40.0     # wall seconds of the node-graph calibration session
START_MARGIN_S = 25.0          # wall seconds for the nodes to start and the recorder to open
ONSET_N = 0.5                  # |f_z| marking the first press of the sequence (alignment)


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


def run_session(mode: str, scene: str, plate: str, out: Path, duration: float,
                model_config: Path | None = None) -> Path:
    """Run the `session` tool once; return the bag folder it recorded."""
    session_exe = Path(sys.prefix) / 'lib' / 'tacforce_ros' / 'session'
    if not session_exe.is_file():
        raise NodePathUnavailable(f'{session_exe} is not installed (run ./run.sh setup)')
    out.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, '-m', 'tacforce_ros.tools.session', mode, '--scene', scene,
               '--array', 'index_tip', '--plate', plate, '--out', str(out),
               '--duration', f'{duration:g}', '--ports', *map(str, _free_ports(3))]
    if model_config is not None:
        command += ['--model', str(model_config)]
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    # A domain of our own, so DDS traffic of other processes on this host stays out.
    env['ROS_DOMAIN_ID'] = str(env.get('TACFORCE_REPRODUCE_DOMAIN', 40 + os.getpid() % 50))
    try:
        done = subprocess.run(command, env=env, capture_output=True, text=True,
                              timeout=duration + 90.0)
    except subprocess.TimeoutExpired as exc:
        raise NodePathUnavailable(f'session {mode} did not stop within {duration + 90:g} s') \
            from exc
    (out / 'session.log').write_text(done.stdout + done.stderr)
    bags = sorted(p for p in out.iterdir() if p.is_dir() and (p / 'metadata.yaml').is_file())
    if not bags:
        raise NodePathUnavailable(f'session {mode} exited {done.returncode} and recorded no bag '
                                  f'(log: {out / "session.log"}): {done.stderr.strip()[-300:]}')
    return bags[-1]


def _seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def bag_streams(bag: Path, hand: HandDescription) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Whole-hand tactile counts, F/T force and joint positions of a bag, by header stamp."""
    from tacforce_ros import bagio
    topics = [bagio.TOPIC_TACTILE, bagio.TOPIC_WRENCH, bagio.TOPIC_JOINTS]
    joint_names = [f'joint_{i}.0' for i in range(16)]
    found: dict[str, tuple[list, list]] = {t: ([], []) for t in topics}
    for topic, _, msg in bagio.read_messages(bag, topics):
        if topic == bagio.TOPIC_TACTILE:
            by_name = {a.name: np.stack([a.x, a.y, a.z], axis=1) for a in msg.arrays}
            if any(by_name.get(a.name, np.empty((0, 3))).shape != (a.n_taxels, 3)
                   for a in hand.arrays):
                continue            # malformed frame: dropped, as the estimator drops it
            value = hand.merge([by_name[a.name] for a in hand.arrays])
        elif topic == bagio.TOPIC_WRENCH:
            f = msg.wrench.force
            value = np.array([f.x, f.y, f.z])
        else:
            order = dict(zip(msg.name, msg.position))
            if not set(joint_names) <= set(order):
                continue
            value = np.array([order[n] for n in joint_names])
        found[topic][0].append(_seconds(msg.header.stamp))
        found[topic][1].append(value)
    streams = {}
    for topic, (times, values) in found.items():
        if len(times) < 2:
            raise NodePathUnavailable(f'{bag}: only {len(times)} messages on {topic}')
        order = np.argsort(times, kind='stable')
        streams[topic] = (np.asarray(times)[order], np.asarray(values, np.float64)[order])
    return streams


def compare_calibration(bag: Path, hand: HandDescription, kinematics: HandKinematics,
                        scene: str, seed: int, model_path: str, static_force: float) -> dict:
    """e_hat of the trained model on the node-recorded session and on the same window simulated
    directly (same scene, seed and simulated-time span)."""
    from tacforce_ros import bagio
    from tacforce_ros.estimation.bag_dataset import dataset_from_bag
    from tacforce_ros.estimation.model_io import load_model
    from tacforce_ros.experiments.calibration_data import simulate_calibration
    bundle = load_model(model_path, hand.array('index_tip'))
    # Frames stamped 0 were stamped before the first /clock: they say nothing about the window.
    tactile_time = [t for t in (_seconds(m.header.stamp) for _, _, m in
                                bagio.read_messages(bag, [bagio.TOPIC_TACTILE])) if t > 0.0]
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


def node_trace(bag: Path, hand: HandDescription, kinematics: HandKinematics, model_config: Path,
               sequence, reference: ClosedLoopTrace, tare_frames: int
               ) -> tuple[ClosedLoopTrace, float]:
    """The node run as a trace on the sequence's clock, and the clock offset used.

    The bag carries the raw streams; f_hat is the same model set applied to the recorded frames,
    tared as the estimator node tares (its first `tare_frames` frames; the estimator's output is
    not recorded). The command player starts its clock at its
    first tick, which the bag does not record: the offset is the delay of the first press
    (|f~_z| > ONSET_N after f_d leaves zero) against the direct run's.
    """
    from tacforce_ros import bagio
    from tacforce_ros.nodes.model_set import load_model_set
    streams = bag_streams(bag, hand)
    t_tac, frames = streams[bagio.TOPIC_TACTILE]
    t_ft, force = streams[bagio.TOPIC_WRENCH]
    t_q, joints = streams[bagio.TOPIC_JOINTS]
    first_f_d = float(sequence.starts[np.argmax(np.any(sequence.end != 0.0, axis=1))])

    def onset(t: np.ndarray, f: np.ndarray) -> float:
        pressed = (t > first_f_d) & (np.abs(f[:, 2]) > ONSET_N)
        if not pressed.any():
            raise NodePathUnavailable(f'{bag}: the finger never pressed (|f_z| <= {ONSET_N} N)')
        return float(t[np.argmax(pressed)])

    offset = onset(t_ft, force) - onset(reference.t, reference.f_tilde)
    models = load_model_set(model_config, hand)
    models.set_tare(frames[:tare_frames])
    array = hand.array('index_tip')
    q_at = joints[np.clip(np.searchsorted(t_q, t_tac), 0, len(t_q) - 1)]
    f_hat = np.stack([kinematics.rotation_between(q, array.frame_id, hand.ft_frame)
                      @ models.estimate(frame).force[0] for q, frame in zip(q_at, frames)])
    t = t_tac - offset
    f_tilde = np.column_stack([np.interp(t_tac, t_ft, force[:, k]) for k in range(3)])
    f_d = np.stack([sequence.force_at(max(x, 0.0)) for x in t])
    return ClosedLoopTrace(t=t, f_d=f_d, f_hat=f_hat, f_tilde=f_tilde), offset


def compare_closed_loop(node: ClosedLoopTrace, direct: ClosedLoopTrace, offset: float) -> dict:
    node_m, direct_m = trace_metrics([node]), trace_metrics([direct])
    difference = abs(node_m['e_tilde_mean'] - direct_m['e_tilde_mean'])
    return {'clock_offset_s': offset, 'node': node_m, 'direct': direct_m,
            'difference_n': difference, 'tolerance_n': AGREEMENT_N['closed_loop_e_tilde'],
            'agree': difference <= AGREEMENT_N['closed_loop_e_tilde']}
