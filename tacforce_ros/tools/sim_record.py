"""sim_record: simulated calibration sessions -> rosbag2 (mcap) bags, one bag per session.

Runs the calibration scenes `calibration_<array>_<plate>` (any array of the hand) and writes
each session as the lab recorder would (recording/sim_session.py).

Example: sim_record --out data/sim --arrays index_tip --plates flat edge --sessions 1 --seconds 10
(a whole-hand campaign that resumes where it stopped: `campaign`)
"""
from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

from tacforce_ros import bagio
from tacforce_ros.hand.description import SIDES, hand_config, load_hand
from tacforce_ros.paths import output_folder
from tacforce_ros.recording.campaign import SessionSlot
from tacforce_ros.recording.sim_session import record_session
from tacforce_ros.sim import load_scene
from tacforce_ros.sim.scene import calibration_scene_name
from tacforce_ros.rig import HELD_OUT_PLATE, TRAINING_PLATES

PLATES = (*TRAINING_PLATES, HELD_OUT_PLATE)
ARRAYS = ('index_tip', 'index_middle')     # the paper's Table I arrays


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='sim_record', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--out', type=output_folder, required=True, help='folder for the bags')
    parser.add_argument('--arrays', nargs='+', default=list(ARRAYS),
                        help='arrays of the hand to press (default: the paper\'s two)')
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
    unknown = sorted(set(args.arrays) - {a.name for a in hand.arrays})
    if unknown:
        parser.error(f'--arrays: not arrays of the hand: {unknown}; known '
                     f'{[a.name for a in hand.arrays]}')
    jobs = [(a, p, s) for a in args.arrays for p in args.plates for s in range(args.sessions)]
    steps = sum(int(round(args.seconds * load_scene(calibration_scene_name(a, p)).tactile_rate))
                for a, p, _ in jobs)
    try:
        with tqdm(total=steps, unit='step', desc='sim_record') as progress:
            for array, plate, session in jobs:
                path = record_session(args.out / SessionSlot(array, plate, session).name, hand,
                                      array, plate, session, args.seconds, args.seed, progress)
                progress.write(f'wrote {path}')
    except bagio.BagError as exc:
        print(f'sim_record: {exc}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
