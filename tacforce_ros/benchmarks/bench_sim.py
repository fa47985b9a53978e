"""bench_sim: simulator speed per scene (simulated s per wall s) and the cost of each effect.

Each scene runs for --seconds of simulated time (closed-loop scenes with a constant torque
command: the physics alone), best of --repeats. Each closed-loop scene then runs as the main job
runs it, with the estimator (the shipped models, config/models/default.yaml) and the force
controller in the loop at 100 Hz, playing the paper's sequence cut at --loop-seconds after the
2 s settle; its wall time per physics step is set against a bare MuJoCo step (mj_step) of the
same compiled model, timed in between: what our layer costs on top of the physics. Each effect
is timed alone on a reference scene of its kind against that scene with no effects, the two
runs interleaved, so the ratio holds even when other work slows the machine. Every scene runs on
the empirical skin (the scene files) and on the magnetic skin (`<scene>@magnetic`, the main
job's default); the magnetic skin's cost is its wall time per simulated second over the
empirical skin's on the same scene, the two interleaved. Targets: calibration >= 50x real time,
closed loop and grasp >= 10x physics alone, >= 15x with the loop, the magnetic skin at most
1.5x the empirical one's time. Writes JSON (--out) and prints a table.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
import warnings

import numpy as np

from tacforce_ros.experiments import paper_reference as paper
from tacforce_ros.hand.description import load_hand
from tacforce_ros.paths import output_file
from tacforce_ros.sim import list_scenes, load_scene, make_simulator
from tacforce_ros.sim.effects import EFFECTS
from tacforce_ros.sim.scene import calibration_scene_name
from tacforce_ros.rig import HELD_OUT_PLATE, TRAINING_PLATES
from tacforce_ros.timing import bare_mujoco_seconds

TARGETS = {'calibration': 50.0, 'closed_loop': 10.0, 'grasp': 10.0,
           'closed_loop_with_control': 15.0}
# The magnetic skin's wall time per simulated second over the empirical skin's, same scene.
SKIN_COST_TARGET = 1.5
MAGNETIC = '@magnetic'
LOOP_SEQUENCE = 'paper_70s'
LOOP_CONTROLLER = 'M3-lambda'       # the closed-loop controller (open loop: K_i = 0)
REFERENCE = {'calibration': 'calibration_index_tip_spherical',
             'closed_loop': 'closed_loop_spherical'}
# Effects that act only in closed-loop physics (torques, the MuJoCo model).
CLOSED_LOOP_ONLY = {'actuator_limits', 'torque_gain_error', 'joint_friction',
                    'kinematic_mismatch', 'contact_offset'}


def bench_scene(name: str):
    """The scene `name`, or with MAGNETIC appended that scene on the magnetic skin."""
    from tacforce_ros.sim.effects.magnetic_skin import with_magnetic_skin
    if not name.endswith(MAGNETIC):
        return load_scene(name)
    scene = load_scene(name[:-len(MAGNETIC)])
    return dataclasses.replace(scene, effects=with_magnetic_skin(scene.effects))


def _runner(scene, hand):
    """A function running one timed pass of `scene`; returns its wall time and sim time."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = make_simulator(scene, hand)
    torque = None
    if scene.kind == 'closed_loop':
        torque = np.zeros(16)
        torque[sim.joints] = (0.0, 0.05, 0.05, 0.03)   # press the finger gently on the plate

    def run(seconds: float) -> tuple[float, float]:
        steps = int(round(seconds / sim.dt))
        sim.reset()
        start = time.perf_counter()
        for _ in range(steps):
            sim.step(torque)
        return time.perf_counter() - start, steps * sim.dt
    return run


def realtime_factors(scenes, hand, seconds: float, repeats: int) -> list[float]:
    """Simulated s per wall s of each scene, best of `repeats`; the scenes' passes are
    interleaved so a busy machine slows them alike and their ratios hold."""
    runners = [_runner(scene, hand) for scene in scenes]
    best = [np.inf] * len(runners)
    for _ in range(repeats):
        for i, run in enumerate(runners):
            wall, simulated = run(seconds)
            best[i] = min(best[i], wall / simulated)
    return [1.0 / b for b in best]


def loop_factors(scene, hand, seconds: float, repeats: int) -> dict:
    """The scene with estimator and controller in the loop (experiments.closed_loop, as the main
    job runs it) and bare mj_step passes of its model, interleaved; best of `repeats`."""
    from tacforce_ros.control.command_sequence import ForceSequence
    from tacforce_ros.estimation.model_set import default_model_config, load_model_set
    from tacforce_ros.experiments.closed_loop import SETTLE_SECONDS, run_closed_loop
    from tacforce_ros.experiments.settings import controller_config, tare_frames
    from tacforce_ros.hand.kinematics import HandKinematics

    kinematics = HandKinematics.for_hand(hand)
    models = load_model_set(default_model_config(hand), hand)
    sequence = ForceSequence.load(LOOP_SEQUENCE).until(seconds)
    config = controller_config(LOOP_CONTROLLER)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = make_simulator(scene, hand)
    steps = int(round((SETTLE_SECONDS + sequence.duration) / sim.dt))
    best_loop = best_bare = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        run_closed_loop(hand, kinematics, scene, 0, config, sequence, models,
                        tare_frames=tare_frames())
        best_loop = min(best_loop, time.perf_counter() - start)
        best_bare = min(best_bare, bare_mujoco_seconds(sim.model, sim.data.qpos, steps))
    simulated = steps * sim.dt
    return {'simulated_seconds': simulated, 'physics_steps': steps,
            'realtime_factor': simulated / best_loop,
            'bare_mujoco_realtime_factor': simulated / best_bare,
            'us_per_step': 1e6 * best_loop / steps,
            'bare_mujoco_us_per_step': 1e6 * best_bare / steps,
            'step_over_bare_mujoco': best_loop / best_bare}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='bench_sim', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=output_file, help='JSON result file')
    parser.add_argument('--seconds', type=float, default=5.0, help='simulated s per run')
    parser.add_argument('--repeats', type=int, default=2, help='runs per measurement (best)')
    parser.add_argument('--scenes', nargs='*', help='scene names, NAME@magnetic for a scene on '
                        'the magnetic skin (default: the calibration scenes of the Table I '
                        'arrays on every plate and every scene file, each on both skins)')
    parser.add_argument('--loop-seconds', type=float, default=25.0,
                        help='seconds of the paper sequence played with the loop closed '
                        '(default 25: the first 9 s in contact); 0 = skip')
    args = parser.parse_args(argv)
    hand = load_hand()
    scenes = args.scenes or [name + skin for name in [
        calibration_scene_name(array, plate) for array in paper.TABLE_I
        for plate in (*TRAINING_PLATES, HELD_OUT_PLATE)] + list_scenes()
        for skin in ('', MAGNETIC)]
    result = {'seconds': args.seconds, 'loop_seconds': args.loop_seconds,
              'repeats': args.repeats, 'targets': {**TARGETS, 'skin_cost': SKIN_COST_TARGET},
              'load_before': os.getloadavg(), 'scenes': {}, 'effects': {}}
    print(f'{"scene":50s} {"kind":12s} {"x real time":>12s} {"target":>7s}')
    for name in scenes:
        scene = bench_scene(name)
        (factor,) = realtime_factors([scene], hand, args.seconds, args.repeats)
        target = TARGETS[scene.kind]
        result['scenes'][name] = {'kind': scene.kind, 'realtime_factor': factor,
                                  'target': target, 'meets_target': factor >= target}
        print(f'{name:50s} {scene.kind:12s} {factor:12.1f} {target:7.0f}'
              f'{"" if factor >= target else "  BELOW"}')
    loop_scenes = [name for name in scenes if result['scenes'][name]['kind'] == 'closed_loop']
    if args.loop_seconds > 0 and loop_scenes:
        target = TARGETS['closed_loop_with_control']
        result['closed_loop_with_control'] = {}
        print(f'\n{"scene, estimator + controller in the loop":54s} {"x real time":>11s} '
              f'{"target":>7s} {"us/step":>8s} {"bare mj_step us":>16s} {"ratio":>6s}')
        for name in loop_scenes:
            row = loop_factors(bench_scene(name), hand, args.loop_seconds, args.repeats)
            row.update(target=target, meets_target=row['realtime_factor'] >= target)
            result['closed_loop_with_control'][name] = row
            print(f"{name:54s} {row['realtime_factor']:11.1f} {target:7.0f} "
                  f"{row['us_per_step']:8.1f} {row['bare_mujoco_us_per_step']:16.1f} "
                  f"{row['step_over_bare_mujoco']:6.1f}"
                  f"{'' if row['meets_target'] else '  BELOW'}")
    skins = [name for name in scenes if not name.endswith(MAGNETIC)
             and name + MAGNETIC in scenes]
    if skins:
        result['skin_cost'] = {}
        print(f'\n{"magnetic skin against empirical (interleaved)":50s} {"empirical":>10s} '
              f'{"magnetic":>10s} {"cost":>6s} {"target":>7s}')
    for name in skins:
        empirical, magnetic = realtime_factors([bench_scene(name), bench_scene(name + MAGNETIC)],
                                               hand, args.seconds, args.repeats)
        cost = empirical / magnetic
        result['skin_cost'][name] = {'empirical_realtime_factor': empirical,
                                     'magnetic_realtime_factor': magnetic, 'cost': cost,
                                     'target': SKIN_COST_TARGET,
                                     'meets_target': cost <= SKIN_COST_TARGET}
        print(f'{name:50s} {empirical:10.1f} {magnetic:10.1f} {cost:6.2f} '
              f'{SKIN_COST_TARGET:7.1f}{"" if cost <= SKIN_COST_TARGET else "  ABOVE"}')
    print(f'\n{"effect (alone)":22s} {"reference scene":32s} {"x real time":>12s} '
          f'{"none":>8s} {"cost per sim s":>15s}')
    bare = {kind: load_scene(ref) for kind, ref in REFERENCE.items()}
    for effect in EFFECTS:
        kind = 'closed_loop' if effect in CLOSED_LOOP_ONLY else 'calibration'
        none, factor = realtime_factors(
            [dataclasses.replace(bare[kind], effects={}),
             dataclasses.replace(bare[kind], effects={effect: {}})],
            hand, args.seconds, args.repeats)
        # Extra wall time per simulated second caused by the effect.
        cost_ms = 1e3 * (1.0 / factor - 1.0 / none)
        result['effects'][effect] = {'scene': REFERENCE[kind], 'realtime_factor': factor,
                                     'none_realtime_factor': none,
                                     'extra_ms_per_sim_s': cost_ms}
        print(f'{effect:22s} {REFERENCE[kind]:32s} {factor:12.1f} {none:8.1f} '
              f'{cost_ms:12.2f} ms')
    result['load_after'] = os.getloadavg()
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))
        print(f'\nwrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
