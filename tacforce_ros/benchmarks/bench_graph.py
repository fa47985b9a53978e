"""bench_graph: how reliably the node graph reproduces the direct (in-process) path.

Runs the closed loop of a force sequence (default the paper's 70 s) on the spherical plate
through the node graph (`session closed_loop`, as a user would) --runs times, each against the
direct path on the same scene and seed (seeds scene seed + k), and one calibration session
(--calibration-seconds of simulated time, 0 = none) against its direct simulation, and a
number of fault runs (--fault-runs, seeds scene seed + k): the closed loop of FAULT_SEQUENCE,
its estimator killed mid-sequence and restarted (see CRASH and crash_metrics). Per run:
e~ and e_track of both paths and their differences, the controller's `safe` and `hold` ticks
after it engaged (watchdog trips), the achieved real-time factor (sim_world's "scene done:"
line), and per recorded stream the messages sharing their stamp with the previous one and, for
the tactile stream, the frames missing from the bag in simulated time (stamp intervals above
1.5 tactile periods; the driver's drops of a repeated instant are not missing). The
calibration session adds samples per simulated second and the fraction of tactile frames paired
into /calibration/sample. Writes JSON and a readable table to --out.

    bench_graph --runs 10 --out out/bench_graph
    bench_graph --runs 3 --no-lockstep --out out/bench_graph_free   # free-running, to compare
    # after `reproduce` (its default, magnetic skin), with the model it trained on that skin:
    bench_graph --skin magnetic --model out/models/M3-lambda.yaml ...
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

from tacforce_ros import bagio, results, topics
from tacforce_ros.bringup.processes import interrupt_on_sigterm, read_cpu_report, unclean_exits
from tacforce_ros.control.command_sequence import ForceSequence
from tacforce_ros.control.force_controller import MODE_HOLD, MODE_SAFE
from tacforce_ros.estimation.model_set import (ModelConfigError, default_model_config,
                                               load_model_set, model_files)
from tacforce_ros.experiments import node_path
from tacforce_ros.experiments.settings import (SKINS, Settings, controller_config, skin_scene,
                                               tare_frames)
from tacforce_ros.hand.description import load_hand
from tacforce_ros.hand.kinematics import TIP_LINKS, HandKinematics
from tacforce_ros.bringup.session_plan import SCENE_DONE_MARKER
from tacforce_ros.paths import output_folder
from tacforce_ros.sim.closed_loop import FRICTION
from tacforce_ros.sim.scene import load_scene

LOOP_SCENE = 'closed_loop_spherical'
CALIBRATION_SCENE = 'calibration_index_tip_spherical'
STREAMS = (topics.TOPIC_TACTILE, topics.TOPIC_WRENCH, topics.TOPIC_JOINTS, topics.TOPIC_SAMPLE,
           topics.TOPIC_CONTROLLER_STATE)
_ACHIEVED = re.compile(r'([0-9.]+)x real time')
_STOPPED = re.compile(r'stopped after ([0-9.]+) s')
TACTILE_PERIOD_NS = 10_000_000      # uSkin frames at 100 Hz (the scenes' tactile_rate)
# The fault run: the estimator killed 45 wall seconds into the session, 8 to 40 s into the
# sequence at 0.2x to 1x real time, and restarted 3 s later, while FAULT_SEQUENCE holds one force
# from 6 to 66 s (a command step during the outage would make the recovery that step's response;
# crash_metrics reports a run where it did). What it asks: the controller in its hold within
# HOLD_WITHIN_S of the last estimate, the fingertip on the plate (normal force above
# CONTACT_MIN_N, shear inside the simulator's friction cone), tracking back under TRACK_N within
# RECOVERY_S of the estimate's return.
CRASH = ('estimator', 45.0, 3.0)
# The hand's driver killed the same way (--driver-kill-runs): what the hand does while its
# commands have stopped, and after the driver is back.
DRIVER_KILL = ('allegro_driver', 45.0, 3.0)
FAULT_SEQUENCE = 'fault_drill'
HOLD_WITHIN_S = 0.1
CONTACT_MIN_N = 0.2
TRACK_N = 0.05
TRACK_WINDOW_S = 0.5
RECOVERY_S = 2.0


def session_seconds(session_dir: Path) -> float | None:
    """Wall seconds the session ran, from start to stop (the session tool's last line)."""
    log = session_dir / 'session.log'
    found = _STOPPED.search(log.read_text(errors='replace')) if log.is_file() else None
    return float(found.group(1)) if found else None


def process_cpu(session_dir: Path) -> dict[str, float]:
    """CPU seconds per process of a session (the session tool's report at its end)."""
    log = session_dir / 'session.log'
    for line in log.read_text(errors='replace').splitlines() if log.is_file() else ():
        cpu = read_cpu_report(line)
        if cpu is not None:
            return cpu
    return {}


def achieved_factor(session_dir: Path) -> float | None:
    """The real-time factor sim_world reports when its scene is done."""
    log = session_dir / 'logs' / 'sim_world.log'
    for line in log.read_text(errors='replace').splitlines() if log.is_file() else ():
        if SCENE_DONE_MARKER in line:
            found = _ACHIEVED.search(line)
            return float(found.group(1)) if found else None
    return None


def stream_counts(bag: Path) -> dict:
    """Per recorded stream: messages, messages sharing their stamp with the previous one, messages
    with bag log time 0; for the tactile stream also the frames missing in simulated time (an
    interval of n periods, n > 1.5, misses round(n) - 1 frames)."""
    stamps: dict[str, list[int]] = {topic: [] for topic in STREAMS}
    log_time_zero = dict.fromkeys(STREAMS, 0)
    for topic, log_time, msg in bagio.read_messages(bag, list(STREAMS)):
        stamps[topic].append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        log_time_zero[topic] += log_time == 0
    counts = {}
    for topic, values in stamps.items():
        if values:
            counts[topic] = {'messages': len(values),
                             'duplicate_stamps': int(np.sum(np.diff(values) == 0)),
                             'log_time_zero': log_time_zero[topic]}
    tactile = np.diff(np.asarray(stamps[topics.TOPIC_TACTILE], np.int64))
    if tactile.size:
        periods = tactile / TACTILE_PERIOD_NS
        counts[topics.TOPIC_TACTILE]['missing_frames'] = int(
            np.sum(np.round(periods[periods > 1.5]) - 1))
    return counts


def watchdog_ticks(bag: Path) -> dict:
    """Controller ticks in `safe`, and in `hold` after it first engaged (a stale estimate ramps
    to the hold), from the recorded /force_controller/state."""
    modes = [msg.mode for _, _, msg in bagio.read_messages(bag, [topics.TOPIC_CONTROLLER_STATE])]
    engaged = next((k for k, mode in enumerate(modes) if mode not in (MODE_HOLD, MODE_SAFE)),
                   len(modes))
    return {'ticks': len(modes), 'safe': sum(mode == MODE_SAFE for mode in modes),
            'hold_after_engaging': sum(mode == MODE_HOLD for mode in modes[engaged:])}


def stale_spells(fresh: np.ndarray, offset: int = 0) -> list[tuple[int, int | None]]:
    """(first stale tick, first fresh tick after it or None) of each spell of stale ticks."""
    edges = np.flatnonzero(np.diff(np.concatenate([[True], fresh, [True]]).astype(np.int8)))
    return [(offset + int(a), offset + int(b) if b < fresh.size else None)
            for a, b in zip(edges[::2], edges[1::2])]


def crash_metrics(t: np.ndarray, modes: list[str], fresh: np.ndarray, age: np.ndarray,
                  f_d: np.ndarray, f_hat: np.ndarray, f_tilde: np.ndarray,
                  tip: np.ndarray) -> dict:
    """What the controller did around an estimator outage, per controller tick of the sequence
    (t s, mode, estimate fresh, the age of the controller's latest valid estimate, f_d, f_hat,
    zeroed F/T f_tilde in {F}, fingertip position in the base frame, whose axes {F} shares:
    pressing the plate is -z). The outage is the longest spell of stale ticks after the
    controller engaged (the drill keeps the estimator down for seconds; any other spell is
    reported as `other_stale_spells`, not judged here); its last estimate is the one the spell's
    first tick was aging (stamped t - age there; where that age is not finite, an invalid
    estimate, the last fresh tick's). Reported: how long after that estimate the controller
    reached its hold, the least normal force on the plate, the most shear per normal force (the
    friction cone: above the simulator's friction coefficient the tip slides) and the tangential
    tip travel from the last fresh tick until the estimate returned, and how long after it
    returned the tracking error |f_d - f_hat|, averaged over TRACK_WINDOW_S, was back under
    TRACK_N."""
    engaged = next((k for k, mode in enumerate(modes) if mode not in (MODE_HOLD, MODE_SAFE)),
                   None)
    spells = [] if engaged is None else stale_spells(np.asarray(fresh[engaged:], bool), engaged)
    if not spells:
        return {'failed': 'the estimate never went stale after the controller engaged'}
    first_stale, back = max(spells, key=lambda spell: (
        len(t) if spell[1] is None else spell[1]) - spell[0])
    if back is None:
        return {'failed': f'the estimate went stale at {t[first_stale]:.2f} s and never returned'}
    others = [(t[a], (t[b] if b is not None else t[-1]) - t[a]) for a, b in spells
              if a != first_stale]
    judged = first_stale if np.isfinite(age[first_stale]) else first_stale - 1
    t_last = t[judged] - age[judged]
    # The drill holds one command over the outage and the recovery; a kill that landed where
    # the command changes (the run went slower than the drill allows for) measures that step.
    span = (t >= t_last) & (t <= t[back] + RECOVERY_S)
    if np.ptp(f_d[span], axis=0).max() > 1e-9:
        return {'failed': f'the outage ({t_last:.2f}-{t[back]:.2f} s of the sequence) and its '
                f'recovery did not fall inside one held command: the run went slower than '
                f'the drill\'s timing allows'}
    hold = next((k for k in range(first_stale, back + 1) if modes[k] == MODE_HOLD), None)
    outage = slice(first_stale - 1, back + 1)
    normal = -f_tilde[outage, 2]
    shear = np.linalg.norm(f_tilde[outage, :2], axis=1)
    travel = np.linalg.norm(tip[outage, :2] - tip[first_stale - 1, :2], axis=1)
    recovered = tracking_back(t, f_d, f_hat, back)
    result = {'last_estimate_s': float(t_last), 'estimate_back_s': float(t[back]),
              'hold_after_s': None if hold is None else float(t[hold] - t_last),
              'least_normal_force_n': float(np.min(normal)),
              'most_shear_per_normal': float(np.max(shear / np.maximum(normal, 1e-9))),
              'tip_travel_mm': float(1e3 * np.max(travel)),
              'tracking_back_after_s': (None if recovered is None
                                        else float(t[recovered] - t[back])),
              'other_stale_spells': [{'at_s': float(at), 'lasted_s': float(lasted)}
                                     for at, lasted in others]}
    result['passed'] = bool(
        result['hold_after_s'] is not None and result['hold_after_s'] <= HOLD_WITHIN_S + 1e-9
        and result['least_normal_force_n'] > CONTACT_MIN_N
        and result['most_shear_per_normal'] < FRICTION
        and result['tracking_back_after_s'] is not None
        and result['tracking_back_after_s'] <= RECOVERY_S + 1e-9)
    return result


def tracking_back(t: np.ndarray, f_d: np.ndarray, f_hat: np.ndarray, since: int) -> int | None:
    """The first tick from `since` on at which |f_d - f_hat|, averaged over the TRACK_WINDOW_S
    before it (every estimate there fresh), is under TRACK_N; None if none is."""
    error = np.linalg.norm(f_d - f_hat, axis=1)         # NaN where the estimate is stale
    window = max(1, int(round(TRACK_WINDOW_S / float(np.median(np.diff(t))))))
    return next((k for k in range(since + window - 1, len(t))
                 if np.all(np.isfinite(error[k - window + 1:k + 1]))
                 and np.mean(error[k - window + 1:k + 1]) < TRACK_N), None)


def driver_kill_metrics(t: np.ndarray, f_d: np.ndarray, f_hat: np.ndarray, f_tilde: np.ndarray,
                        joints: np.ndarray) -> dict:
    """What the hand did while its driver was down, per controller tick of the sequence (t s,
    f_d, f_hat, zeroed F/T f_tilde in {F}) and the joint states' stamps on the same clock: the
    outage is the longest gap between joint states (the driver publishes them); reported, the
    normal force on the plate over the 0.5 s before it, its least and largest during it and in
    the 2 s after the joints came back, and how long after that the tracking error was back
    under TRACK_N."""
    if joints.size < 2:
        return {'failed': 'fewer than two joint states in the sequence'}
    gap = int(np.argmax(np.diff(joints)))
    off, on = float(joints[gap]), float(joints[gap + 1])
    normal = -f_tilde[:, 2]

    def span(a: float, b: float) -> np.ndarray:
        return normal[(t >= a) & (t < b)]

    before, during, after = span(off - 0.5, off), span(off, on), span(on, on + 2.0)
    if not (before.size and during.size and after.size):
        return {'failed': f'no controller ticks around the joints\' gap {off:.2f}-{on:.2f} s'}
    back = int(np.searchsorted(t, on))
    recovered = tracking_back(t, f_d, f_hat, back)
    return {'joints_stopped_s': off, 'joints_back_s': on, 'outage_s': on - off,
            'normal_force_before_n': float(np.mean(before)),
            'normal_force_during_n': [float(np.min(during)), float(np.max(during))],
            'normal_force_after_n': [float(np.min(after)), float(np.max(after))],
            'tracking_back_after_s': (None if recovered is None
                                      else float(t[recovered] - on))}


def driver_kill_run(k: int, args, out: Path) -> dict:
    """FAULT_SEQUENCE's closed loop with the hand's driver killed (SIGKILL: its torque commands
    stop mid-stream) and restarted, DRIVER_KILL; free-running, since in lockstep simulated time
    waits for the joint stream the dead driver no longer sends. The emulated hand keeps the last
    torque it was sent (the Allegro V4 firmware's behaviour when commands stop is not
    documented: the emulator takes the worst case)."""
    seed = load_scene(LOOP_SCENE).seed + k
    sequence = ForceSequence.load(FAULT_SEQUENCE)
    session_dir = out / f'driver_kill_{k}'
    bag = node_path.run_session('closed_loop', args.loop_scene, 'spherical', session_dir,
                                node_path.closed_loop_session_seconds(sequence.duration),
                                args.model, seed=seed, lockstep=False, crash=DRIVER_KILL,
                                sequence=sequence.source)
    trace, start = node_path.node_trace(bag, sequence, tare_frames())
    joints = np.array(sorted(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9 - start
                             for _, _, msg in bagio.read_messages(bag, [topics.TOPIC_JOINTS])))
    joints = joints[(joints >= 0.0) & (joints <= sequence.duration)]
    return {'run': k, 'seed': seed, 'sequence': FAULT_SEQUENCE,
            'crash': {'node': DRIVER_KILL[0], 'at_wall_s': DRIVER_KILL[1],
                      'down_wall_s': DRIVER_KILL[2]},
            **driver_kill_metrics(trace.t, trace.f_d, trace.f_hat, trace.f_tilde, joints),
            'exit_codes': node_path.session_exit_codes(session_dir), 'bag': str(bag)}


def crash_run(k: int, args, kinematics, out: Path) -> dict:
    """The closed loop of FAULT_SEQUENCE with the estimator killed and restarted mid-sequence (the
    session's fault drill, CRASH), read back from its bag."""
    seed = load_scene(LOOP_SCENE).seed + k
    sequence = ForceSequence.load(FAULT_SEQUENCE)
    session_dir = out / f'crash_{k}'
    bag = node_path.run_session('closed_loop', args.loop_scene, 'spherical', session_dir,
                                node_path.closed_loop_session_seconds(sequence.duration),
                                args.model, seed=seed, lockstep=args.lockstep, crash=CRASH,
                                sequence=sequence.source)
    return {'run': k, 'seed': seed, 'sequence': FAULT_SEQUENCE,
            'crash': {'node': CRASH[0], 'at_wall_s': CRASH[1], 'down_wall_s': CRASH[2]},
            'achieved_real_time_factor': achieved_factor(session_dir),
            **crash_report(bag, kinematics, sequence),
            'exit_codes': node_path.session_exit_codes(session_dir), 'bag': str(bag)}


def crash_report(bag: Path, kinematics, sequence) -> dict:
    """crash_metrics of a recorded closed-loop bag."""
    trace, start = node_path.node_trace(bag, sequence, tare_frames())
    states = sorted((msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, msg.mode,
                     msg.estimate_fresh, msg.estimate_age, tuple(msg.q))
                    for _, _, msg in bagio.read_messages(bag, [topics.TOPIC_CONTROLLER_STATE]))
    states = [s for s in states if 0.0 <= s[0] - start <= sequence.duration]
    joints = kinematics.finger_joints('index')
    tips = []
    for *_, q in states:
        q16 = np.zeros(16)
        q16[joints] = q
        tips.append(kinematics.frame_pose(q16, TIP_LINKS['index'])[1])
    return crash_metrics(trace.t, [s[1] for s in states], np.array([s[2] for s in states]),
                         np.array([s[3] for s in states]), trace.f_d, trace.f_hat, trace.f_tilde,
                         np.asarray(tips))


def closed_loop_run(k: int, args, hand, kinematics, sequence, out: Path,
                    compose: bool = False) -> dict:
    seed = load_scene(LOOP_SCENE).seed + k
    session_dir = out / f'closed_loop_{k}{"_composed" if compose else ""}'
    compared, *_, bag = node_path.closed_loop_against_direct(
        hand, kinematics, args.loop_scene, 'spherical', seed, args.model, sequence, session_dir,
        controller_config('M3-lambda'), tare_frames(), lockstep=args.lockstep, compose=compose)
    node, direct_m = compared['node'], compared['direct']
    return {'run': k, 'seed': seed, 'composed': compose,
            'session_wall_s': session_seconds(session_dir),
            'cpu_s': process_cpu(session_dir),
            'achieved_real_time_factor': achieved_factor(session_dir),
            'e_tilde': {'node': node['e_tilde_mean'], 'direct': direct_m['e_tilde_mean']},
            'e_track': {'node': node['e_track_mean'], 'direct': direct_m['e_track_mean']},
            'e_tilde_difference': compared['difference_n'],
            'e_track_difference': compared.get('e_track_difference_n'),
            'watchdog': watchdog_ticks(bag), 'streams': stream_counts(bag),
            'exit_codes': compared['exit_codes'], 'bag': str(bag)}


def calibration_run(args, hand, kinematics, out: Path) -> dict:
    seed = load_scene(CALIBRATION_SCENE).seed
    session_dir = out / 'calibration'
    scene = skin_scene(out / 'scenes', CALIBRATION_SCENE, args.skin)
    bag = node_path.run_session('calibration', scene, 'spherical', session_dir,
                                args.calibration_seconds, seed=seed, lockstep=args.lockstep)
    compared = node_path.compare_calibration(bag, hand, kinematics, scene, seed,
                                             str(model_files(args.model)['index_tip']),
                                             Settings().static_force)
    streams = stream_counts(bag)
    start, stop = compared['window_s']
    samples = streams.get(topics.TOPIC_SAMPLE, {}).get('messages', 0)
    frames = streams.get(topics.TOPIC_TACTILE, {}).get('messages', 0)
    return {'seed': seed, 'achieved_real_time_factor': achieved_factor(session_dir),
            'samples_per_simulated_s': samples / (stop - start) if stop > start else 0.0,
            'tactile_frames_paired': samples / frames if frames else 0.0,
            'e_hat': {'node': compared['node']['e_hat_mean'],
                      'direct': compared['direct']['e_hat_mean']},
            'e_hat_difference': compared['difference_n'], 'streams': streams,
            'exit_codes': node_path.session_exit_codes(session_dir), 'bag': str(bag)}


def summary(runs: list[dict]) -> dict:
    """How many runs agree with the direct path within the node graph's agreement tolerances and
    had no `safe` tick; mean session wall time and CPU seconds (the nodes, the simulator)."""
    done = [r for r in runs if 'failed' not in r]
    tolerance = {'e_tilde': 0.03, 'e_track': 0.02}     # the node graph's must-show
    return {
        'runs': len(runs), 'e_tilde_tolerance': tolerance['e_tilde'],
        'e_track_tolerance': tolerance['e_track'],
        'agree': sum(r['e_tilde_difference'] <= tolerance['e_tilde']
                     and r['e_track_difference'] is not None
                     and r['e_track_difference'] <= tolerance['e_track'] for r in done),
        'no_safe_ticks': sum(r['watchdog']['safe'] == 0 for r in done),
        'mean_session_wall_s': float(np.mean([r['session_wall_s'] or np.nan for r in done]))
        if done else None,
        'mean_cpu_s_nodes': float(np.mean([nodes_cpu(r) for r in done])) if done else None,
        'mean_cpu_s_simulator': float(np.mean([r['cpu_s'].get('sim_world', np.nan)
                                               for r in done])) if done else None}


def nodes_cpu(run: dict) -> float:
    """CPU seconds of a run's node processes (all but the simulator)."""
    return sum(v for name, v in run['cpu_s'].items() if name != 'sim_world')


def _n(value, digits: int = 3) -> str:
    return '-' if value is None else f'{value:.{digits}f}'


def _part(name: str, part: dict | None, describe) -> list[str]:
    """The table's lines of a one-off part (calibration session, fault run): its failure as
    such, else `describe(part)`."""
    if not part:
        return []
    return ['', f'{name}: ' + (f'FAILED: {part["failed"]}' if 'failed' in part
                               else describe(part))]


def _calibration_text(c: dict) -> str:
    return (f'{_n(c["samples_per_simulated_s"], 1)} samples per simulated s, '
            f'{c["tactile_frames_paired"]:.1%} of tactile frames paired, e_hat node '
            f'{_n(c["e_hat"]["node"])} vs direct {_n(c["e_hat"]["direct"])} N, real-time factor '
            f'{_n(c["achieved_real_time_factor"], 2)}; duplicate stamps / log time 0: '
            + ', '.join(f'{t} {v["duplicate_stamps"]}/{v["log_time_zero"]}'
                        for t, v in c['streams'].items()))


def _crash_text(f: dict) -> str:
    return (f'{f["crash"]["node"]} killed {f["crash"]["at_wall_s"]:g} s into the session, '
            f'restarted {f["crash"]["down_wall_s"]:g} s later; last estimate at '
            f'{f["last_estimate_s"]:.2f} s of the sequence, back at {f["estimate_back_s"]:.2f} s: '
            f'hold {_n(f["hold_after_s"])} s after it (<= {HOLD_WITHIN_S:g}); least normal force '
            f'{f["least_normal_force_n"]:.2f} N (> {CONTACT_MIN_N:g}), most shear per normal '
            f'force {f["most_shear_per_normal"]:.2f} (< friction {FRICTION:g}), tip travel '
            f'{f["tip_travel_mm"]:.2f} mm; tracking under {TRACK_N:g} N '
            f'{_n(f["tracking_back_after_s"], 2)} s after the estimate returned '
            f'(<= {RECOVERY_S:g}): {"passed" if f["passed"] else "FAILED"}'
            + ''.join(f'; also stale {o["lasted_s"]:.3f} s at {o["at_s"]:.2f} s'
                      for o in f.get('other_stale_spells', [])))


def _driver_kill_text(d: dict) -> str:
    during, after = d['normal_force_during_n'], d['normal_force_after_n']
    return (f'{d["crash"]["node"]} killed {d["crash"]["at_wall_s"]:g} s into the session, '
            f'restarted {d["crash"]["down_wall_s"]:g} s later: no joint states from '
            f'{d["joints_stopped_s"]:.2f} to {d["joints_back_s"]:.2f} s of the sequence '
            f'({d["outage_s"]:.2f} s); normal force {d["normal_force_before_n"]:.2f} N before, '
            f'{during[0]:.2f}-{during[1]:.2f} N while the driver was down (the hand kept the '
            f'last torque), {after[0]:.2f}-{after[1]:.2f} N in the 2 s after it was back; '
            + (f'tracking under {TRACK_N:g} N {d["tracking_back_after_s"]:.2f} s after that'
               if d['tracking_back_after_s'] is not None else
               f'tracking not back under {TRACK_N:g} N before the sequence ended'))


def table(result: dict) -> str:
    lines = [f'bench_graph ({"lockstep" if result["lockstep"] else "free-running"}, '
             f'{result["sequence"]}, model {result["model"]}, {result["skin"]} skin)', '',
             '| run | seed | processes | e~ node | e~ direct | diff | e_track node | '
             'e_track direct | diff | safe ticks | hold after engaging | real-time factor | '
             'session wall s | CPU s nodes / simulator | duplicate stamps '
             '(tactile/wrench/joints/state) | tactile frames missing |',
             '|' + '---|' * 16]
    runs = sorted(result['closed_loop'] + result['closed_loop_composed'],
                  key=lambda r: (r['run'], r['composed']))
    for r in runs:
        processes = 'one (composed)' if r['composed'] else 'one per node'
        if 'failed' in r:
            lines.append(f'| {r["run"]} | {r["seed"]} | {processes} | FAILED: {r["failed"]} |')
            continue
        s = r['streams']
        duplicates = '/'.join(str(s.get(t, {}).get('duplicate_stamps', '-')) for t in (
            topics.TOPIC_TACTILE, topics.TOPIC_WRENCH, topics.TOPIC_JOINTS,
            topics.TOPIC_CONTROLLER_STATE))
        lines.append(
            f'| {r["run"]} | {r["seed"]} | {processes} | {_n(r["e_tilde"]["node"])} | '
            f'{_n(r["e_tilde"]["direct"])} | {_n(r["e_tilde_difference"])} | '
            f'{_n(r["e_track"]["node"])} | {_n(r["e_track"]["direct"])} | '
            f'{_n(r["e_track_difference"])} | {r["watchdog"]["safe"]} | '
            f'{r["watchdog"]["hold_after_engaging"]} | '
            f'{_n(r["achieved_real_time_factor"], 2)} | {_n(r["session_wall_s"], 0)} | '
            f'{nodes_cpu(r):.0f} / {_n(r["cpu_s"].get("sim_world"), 0)} | {duplicates} | '
            f'{s.get(topics.TOPIC_TACTILE, {}).get("missing_frames", "-")} |')
    for key, name in (('summary', 'one process per node'),
                      ('summary_composed', 'composed in one process')):
        m = result[key]
        if m['runs']:
            lines += ['', f'{name}: agree (|e~ diff| <= {m["e_tilde_tolerance"]} N and |e_track '
                      f'diff| <= {m["e_track_tolerance"]} N): {m["agree"]} of {m["runs"]}; with '
                      f'zero safe ticks: {m["no_safe_ticks"]} of {m["runs"]}; mean session '
                      f'{_n(m["mean_session_wall_s"], 0)} s wall, CPU '
                      f'{_n(m["mean_cpu_s_nodes"], 0)} s nodes + '
                      f'{_n(m["mean_cpu_s_simulator"], 0)} s simulator']
    lines += _part('calibration session', result.get('calibration'), _calibration_text)
    faults = result.get('fault_runs', [])
    for f in faults:
        lines += _part(f'fault run {f["run"]} (seed {f["seed"]}, {FAULT_SEQUENCE})', f,
                       _crash_text)
    if faults:
        lines += ['', f'fault runs passed: {sum(f.get("passed", False) for f in faults)} of '
                  f'{len(faults)}']
    for d in result.get('driver_kill_runs', []):
        lines += _part(f'driver kill {d["run"]} (seed {d["seed"]}, {FAULT_SEQUENCE}, '
                       'free-running)', d, _driver_kill_text)
    lines += ['', 'nodes that did not end cleanly when their session stopped them: '
              + (', '.join(unclean_stops(result)) or 'none')]
    return '\n'.join(lines)


def unclean_stops(result: dict) -> list[str]:
    """Each node, of every session of a result, that ended otherwise than as asked."""
    sessions = [(f'closed loop {r["run"]}{" composed" if r["composed"] else ""}', r)
                for r in result['closed_loop'] + result['closed_loop_composed']]
    sessions += [('calibration', result['calibration'])] if result.get('calibration') else []
    sessions += [(f'fault run {f["run"]}', f) for f in result.get('fault_runs', [])]
    sessions += [(f'driver kill {d["run"]}', d) for d in result.get('driver_kill_runs', [])]
    return [f'{name}: {node} exit code {code}' for name, run in sessions
            for node, code in unclean_exits(run.get('exit_codes', {})).items()]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog='bench_graph', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--runs', type=int, default=3, help='closed-loop runs (default 3)')
    parser.add_argument('--sequence', default='paper_70s', help='force command sequence')
    parser.add_argument('--model', type=Path,
                        help='estimator models YAML (index_tip closes the loop); default the '
                        'shipped models, trained on the empirical skin')
    parser.add_argument('--calibration-seconds', type=float, default=40.0,
                        help='simulated seconds of the calibration session; 0: none')
    parser.add_argument('--compose', action='store_true',
                        help='each closed-loop run also with the nodes composed in one process')
    parser.add_argument('--fault-runs', type=int, default=3,
                        help=f'fault runs: the closed loop of {FAULT_SEQUENCE} with the estimator '
                        'killed mid-sequence and restarted (default 3; 0: none)')
    parser.add_argument('--driver-kill-runs', type=int, default=0,
                        help=f'runs of {FAULT_SEQUENCE} with the hand\'s driver killed '
                        'mid-sequence and restarted: what the hand does meanwhile (default 0)')
    parser.add_argument('--lockstep', action=argparse.BooleanOptionalAction, default=True,
                        help='sessions in lockstep (default) or free-running at real time')
    parser.add_argument('--skin', choices=SKINS, default='empirical',
                        help='the simulated skin of every session (default empirical, the '
                        'skin the shipped models were trained on; magnetic needs a --model '
                        'trained on it, e.g. `reproduce`\'s out/models/M3-lambda.yaml)')
    parser.add_argument('--out', type=output_folder, default='out/bench_graph',
                        help='folder for bench_graph.json and bench_graph.md')
    parser.add_argument('--sessions', type=output_folder, default='out/bench_graph',
                        help='folder for the sessions (scenes, logs, bags)')
    args = parser.parse_args(argv)
    interrupt_on_sigterm()      # its finally blocks stop the processes it started
    if min(args.runs, args.calibration_seconds, args.fault_runs, args.driver_kill_runs) < 0:
        parser.error('--runs, --calibration-seconds, --fault-runs and --driver-kill-runs must '
                     'be >= 0')
    hand = load_hand()
    if args.model is None:
        if args.skin != 'empirical':
            parser.error(f'--skin {args.skin} needs a --model trained on that skin: the shipped '
                         'models were trained on the empirical one')
        args.model = default_model_config(hand)
    kinematics = HandKinematics.for_hand(hand)
    try:
        load_model_set(args.model, hand)        # a bad model list fails before any session
        if 'index_tip' not in model_files(args.model):
            raise ModelConfigError(f'{args.model}: no model for index_tip, which closes the loop')
    except ModelConfigError as exc:
        parser.error(str(exc))
    sequence = ForceSequence.load(args.sequence)
    args.loop_scene = skin_scene(args.sessions / 'scenes', LOOP_SCENE, args.skin)
    command = 'bench_graph ' + ' '.join(sys.argv[1:] if argv is None else argv)
    result: dict = {'provenance': results.provenance(), 'command': command,
                    'lockstep': args.lockstep, 'sequence': args.sequence, 'skin': args.skin,
                    'model': str(args.model), 'closed_loop': [], 'closed_loop_composed': []}
    for k in range(args.runs):
        for compose in (False, True) if args.compose else (False,):
            try:
                run = closed_loop_run(k, args, hand, kinematics, sequence, args.sessions,
                                      compose)
            except (node_path.NodePathUnavailable, OSError, ValueError) as exc:
                run = {'run': k, 'seed': load_scene(LOOP_SCENE).seed + k, 'composed': compose,
                       'failed': str(exc)}
            result['closed_loop_composed' if compose else 'closed_loop'].append(run)
            print(f'run {k}{" composed" if compose else ""}: ' + (
                run.get('failed') or f'e~ diff {run["e_tilde_difference"]:.3f} N, e_track diff '
                f'{_n(run["e_track_difference"])} N, safe ticks {run["watchdog"]["safe"]}'),
                flush=True)
    if args.calibration_seconds > 0:
        try:
            result['calibration'] = calibration_run(args, hand, kinematics, args.sessions)
        except (node_path.NodePathUnavailable, OSError, ValueError) as exc:
            result['calibration'] = {'failed': str(exc)}
    result['fault_runs'] = []
    for k in range(args.fault_runs):
        try:
            fault = crash_run(k, args, kinematics, args.sessions)
        except (node_path.NodePathUnavailable, OSError, ValueError) as exc:
            fault = {'run': k, 'seed': load_scene(LOOP_SCENE).seed + k, 'failed': str(exc)}
        result['fault_runs'].append(fault)
        print(f'fault run {k}: ' + (fault.get('failed') or
                                    ('passed' if fault['passed'] else 'FAILED')), flush=True)
    result['driver_kill_runs'] = []
    for k in range(args.driver_kill_runs):
        try:
            kill = driver_kill_run(k, args, args.sessions)
        except (node_path.NodePathUnavailable, OSError, ValueError) as exc:
            kill = {'run': k, 'seed': load_scene(LOOP_SCENE).seed + k, 'failed': str(exc)}
        result['driver_kill_runs'].append(kill)
        print(f'driver kill {k}: ' + (kill.get('failed') or _driver_kill_text(kill)), flush=True)
    for key in ('closed_loop', 'closed_loop_composed'):
        result['summary' if key == 'closed_loop' else 'summary_composed'] = summary(result[key])
    runs = result['closed_loop'] + result['closed_loop_composed']
    _, md_path = results.write(args.out, 'bench_graph', result, lambda r: (
        results.header(r, 'The node graph against the direct path', r['command']) + '\n'
        + table(r) + '\n'))
    print(md_path.read_text())
    failed = (any('failed' in r for r in runs + result['fault_runs']
                  + result['driver_kill_runs'])
              or 'failed' in result.get('calibration', {}))
    sys.exit(1 if failed else 0)


if __name__ == '__main__':
    main()
