"""bench_sim: simulator speed per scene (simulated s per wall s) and the cost of each effect.

Each scene runs for --seconds of simulated time (closed-loop scenes with a constant torque
command, the open-loop load of a force controller); each effect is timed alone on a reference
scene of its kind against the same scene with no effects, in the same run, so the ratio holds
even on a busy machine. Targets: calibration >= 50x real time, closed loop >= 10x.
Writes JSON (--out) and prints a table.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from tacforce_ros.hand.description import load_hand
from tacforce_ros.sim import list_scenes, load_scene, make_simulator
from tacforce_ros.sim.effects import EFFECTS

TARGETS = {'calibration': 50.0, 'closed_loop': 10.0}
REFERENCE = {'calibration': 'calibration_index_tip_spherical',
             'closed_loop': 'closed_loop_spherical'}
# Effects that act only in closed-loop physics (torques, the MuJoCo model).
CLOSED_LOOP_ONLY = {'actuator_limits', 'torque_gain_error', 'joint_friction',
                    'kinematic_mismatch', 'contact_offset'}


def realtime_factor(scene, hand, seconds: float, repeats: int) -> float:
    """Best of `repeats` runs: simulated seconds per wall second."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = make_simulator(scene, hand)
    torque = None
    if scene.kind == 'closed_loop':
        torque = np.zeros(16)
        torque[sim.joints] = (0.0, 0.05, 0.05, 0.03)   # press the finger gently on the plate
    steps = int(round(seconds / sim.dt))
    best = np.inf
    for _ in range(repeats):
        sim.reset()
        start = time.perf_counter()
        for _ in range(steps):
            sim.step(torque)
        best = min(best, time.perf_counter() - start)
    return steps * sim.dt / best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='bench_sim', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=Path, help='JSON result file')
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
        factor = realtime_factor(scene, hand, args.seconds, args.repeats)
        target = TARGETS[scene.kind]
        result['scenes'][name] = {'kind': scene.kind, 'realtime_factor': factor,
                                  'target': target, 'meets_target': factor >= target}
        print(f'{name:40s} {scene.kind:12s} {factor:12.1f} {target:7.0f}'
              f'{"" if factor >= target else "  BELOW"}')
    print(f'\n{"effect (alone)":22s} {"reference scene":32s} {"x real time":>12s} '
          f'{"none":>8s} {"cost per sim s":>15s}')
    bare = {kind: load_scene(ref) for kind, ref in REFERENCE.items()}
    none = {kind: realtime_factor(dataclasses.replace(s, effects={}), hand, args.seconds,
                                  args.repeats) for kind, s in bare.items()}
    for effect in EFFECTS:
        kind = 'closed_loop' if effect in CLOSED_LOOP_ONLY else 'calibration'
        alone = dataclasses.replace(bare[kind], effects={effect: {}})
        factor = realtime_factor(alone, hand, args.seconds, args.repeats)
        # Extra wall time per simulated second caused by the effect.
        cost_ms = 1e3 * (1.0 / factor - 1.0 / none[kind])
        result['effects'][effect] = {'scene': REFERENCE[kind], 'realtime_factor': factor,
                                     'none_realtime_factor': none[kind],
                                     'extra_ms_per_sim_s': cost_ms}
        print(f'{effect:22s} {REFERENCE[kind]:32s} {factor:12.1f} {none[kind]:8.1f} '
              f'{cost_ms:12.2f} ms')
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2))
        print(f'\nwrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
