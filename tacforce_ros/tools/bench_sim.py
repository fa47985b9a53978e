"""bench_sim: simulator speed per scene (simulated s per wall s) and the cost of each effect.

Each scene runs for --seconds of simulated time (closed-loop scenes with a constant torque
command, the open-loop load of a force controller), best of --repeats. Each effect is timed
alone on a reference scene of its kind against that scene with no effects, the two runs
interleaved, so the ratio holds even when other work slows the machine. Targets: calibration >= 50x real time, closed loop >= 10x.
Writes JSON (--out) and prints a table.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import warnings

import numpy as np

from tacforce_ros.hand.description import load_hand
from tacforce_ros.paths import output_file
from tacforce_ros.sim import list_scenes, load_scene, make_simulator
from tacforce_ros.sim.effects import EFFECTS

TARGETS = {'calibration': 50.0, 'closed_loop': 10.0}
REFERENCE = {'calibration': 'calibration_index_tip_spherical',
             'closed_loop': 'closed_loop_spherical'}
# Effects that act only in closed-loop physics (torques, the MuJoCo model).
CLOSED_LOOP_ONLY = {'actuator_limits', 'torque_gain_error', 'joint_friction',
                    'kinematic_mismatch', 'contact_offset'}


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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='bench_sim', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=output_file, help='JSON result file')
    parser.add_argument('--seconds', type=float, default=5.0, help='simulated s per run')
    parser.add_argument('--repeats', type=int, default=2, help='runs per measurement (best)')
    parser.add_argument('--scenes', nargs='*', help='scene names (default: all)')
    args = parser.parse_args(argv)
    hand = load_hand()
    scenes = args.scenes or list_scenes()
    result = {'seconds': args.seconds, 'repeats': args.repeats, 'targets': TARGETS,
              'scenes': {}, 'effects': {}}
    print(f'{"scene":40s} {"kind":12s} {"x real time":>12s} {"target":>7s}')
    for name in scenes:
        scene = load_scene(name)
        (factor,) = realtime_factors([scene], hand, args.seconds, args.repeats)
        target = TARGETS[scene.kind]
        result['scenes'][name] = {'kind': scene.kind, 'realtime_factor': factor,
                                  'target': target, 'meets_target': factor >= target}
        print(f'{name:40s} {scene.kind:12s} {factor:12.1f} {target:7.0f}'
              f'{"" if factor >= target else "  BELOW"}')
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
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))
        print(f'\nwrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
