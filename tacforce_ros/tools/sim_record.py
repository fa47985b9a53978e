"""sim_record: simulated calibration sessions -> rosbag2 (mcap) bags, one bag per session.

Runs the calibration scenes `calibration_<array>_<plate>` and writes the same topics as the lab
recorder (docs/CONTRACTS.md), plus /sim/contact_force (ground truth in {S0}). Session metadata
says source 'sim', the scene and the seed. A message the transport effect drops is not written,
as in a lab recording.

Example: sim_record --out data/sim --arrays index_tip --plates flat edge --sessions 1 --seconds 10
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tacforce_ros import bagio, topics
from tacforce_ros.hand.description import SIDES, HandDescription, hand_config, load_hand
from tacforce_ros.paths import output_folder
from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim.scene import session_seed

PLATES = ('button', 'flat', 'fillet', 'convex', 'edge', 'spherical')
ARRAYS = ('index_tip', 'index_middle')


def record_session(out_dir: Path, hand: HandDescription, array: str, plate: str,
                   session: int, seconds: float, base_seed: int, progress: tqdm) -> Path:
    scene = load_scene(f'calibration_{array}_{plate}')
    seed = session_seed(base_seed, array, plate, session)
    sim = make_simulator(scene, hand, seed=seed)
    taxel_array = hand.array(array)
    joint_names = [f'joint_{i}.0' for i in range(16)]
    path = out_dir / f'{array}_{plate}_s{session}'
    metadata = bagio.session_metadata(
        array=array, plate=plate, hand_side=hand.side, source='sim', scene=scene.name,
        seed=seed, operator_notes=f'simulated operator, session {session}')
    start_ns = time.time_ns()
    with bagio.CalibrationBagWriter(path, metadata) as writer:
        for k in range(int(round(seconds / sim.dt))):
            sample = sim.step()
            stamp = start_ns + int(round(sample.t * 1e9))
            tactile = wrench = joints = None
            if sample.delivered['tactile']:
                tactile = bagio.tactile_hand(stamp, hand, sample.taxel_counts,
                                             sample.temperatures, sample.t + start_ns * 1e-9, k)
                writer.write(topics.TOPIC_TACTILE, stamp, tactile)
            if sample.delivered['ft']:
                wrench = bagio.wrench_stamped(stamp, hand.ft_frame, sample.ft_wrench)
                writer.write(topics.TOPIC_WRENCH, stamp, wrench)
            if sample.delivered['joints']:
                joints = bagio.joint_state(stamp, joint_names, sample.q, sample.qdot)
                writer.write(topics.TOPIC_JOINTS, stamp, joints)
            if tactile is not None and wrench is not None and joints is not None:
                pressed = tactile.arrays[hand.index(array)]
                writer.write(topics.TOPIC_SAMPLE, stamp,
                             bagio.calibration_sample(stamp, pressed, wrench, joints))
            truth = np.concatenate([sample.true_force, np.zeros(3)])
            writer.write(topics.TOPIC_SIM_CONTACT, stamp,
                         bagio.wrench_stamped(stamp, taxel_array.frame_id, truth))
            progress.update(1)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='sim_record', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=output_folder, required=True, help='folder for the bags')
    parser.add_argument('--arrays', nargs='+', default=list(ARRAYS), choices=ARRAYS)
    parser.add_argument('--plates', nargs='+', default=list(PLATES), choices=PLATES)
    parser.add_argument('--sessions', type=int, default=4, help='sessions per plate and array')
    parser.add_argument('--seconds', type=float, default=100.0, help='length of each session')
    parser.add_argument('--seed', type=int, default=0, help='base seed of all sessions')
    parser.add_argument('--hand-side', choices=SIDES, default='right',
                        help='the simulated hand (its description config/hand/allegro_<side>_uskin'
                        '.yaml)')
    args = parser.parse_args(argv)
    if args.sessions < 1 or args.seconds <= 0:
        parser.error('--sessions must be >= 1 and --seconds > 0')
    hand = load_hand(hand_config(args.hand_side))
    jobs = [(a, p, s) for a in args.arrays for p in args.plates for s in range(args.sessions)]
    steps = sum(int(round(args.seconds * load_scene(f'calibration_{a}_{p}').tactile_rate))
                for a, p, _ in jobs)
    try:
        with tqdm(total=steps, unit='step', desc='sim_record') as progress:
            for array, plate, session in jobs:
                path = record_session(args.out, hand, array, plate, session, args.seconds,
                                      args.seed, progress)
                progress.write(f'wrote {path}')
    except bagio.BagError as exc:
        print(f'sim_record: {exc}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
