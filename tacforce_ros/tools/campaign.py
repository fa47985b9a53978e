"""campaign: plan, check and run a calibration campaign over the arrays of the whole hand.

    campaign plan FOLDER [--arrays ...] [--plates ...] [--sessions N] [--seconds S]
        writes FOLDER/campaign.yaml and prints the sessions in recording order with the time
        they take (default: all 18 arrays, the five training plates, 2 x 100 s each).
    campaign status FOLDER
        judges every bag not yet judged (force range, shear directions, rests), moves a poor one
        to FOLDER/rejected/ with the reasons, and prints what counts and what is due. On the
        rig: `ros2 launch tacforce_ros calibration.launch.py sim:=false hand_side:=SIDE
        campaign:=FOLDER`
        records the next due session into FOLDER (coverage_view shows its coverage live).
    campaign run FOLDER --sim
        records every due session in the simulator (the operator model presses unattended) and
        judges it; a session judged poor is recorded again with the next seed (at most
        SIM_ROUNDS rounds). A session is recorded in FOLDER/.recording/ and moved into FOLDER
        when its bag is closed: an interrupted run leaves it there, and the next run removes it
        and records it again; finished sessions are never recorded again.

Then: `train FOLDER --out MODELS` trains every array of the campaign.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from tqdm import tqdm

from tacforce_ros import bagio
from tacforce_ros.estimation.dataset import DatasetError
from tacforce_ros.rig import TRAINING_PLATES
from tacforce_ros.estimation.preprocessing import StaticSegmentError
from tacforce_ros.hand.description import SIDES, hand_config, load_hand
from tacforce_ros.recording.campaign import (Campaign, CampaignError, CampaignPlan, SessionSlot,
                                             verdict_line)
from tacforce_ros.sim.scene import SceneError, calibration_scene_name, load_scene

RECORDING = '.recording'     # sessions being recorded; moved up into the campaign when closed
# A simulated session whose coverage is poor is recorded again with the next seed; a scene
# that cannot meet the limits at all stops after this many rounds instead of running on.
SIM_ROUNDS = 3


def _hand_and_kinematics(side: str):
    from tacforce_ros.hand.kinematics import HandKinematics
    hand = load_hand(hand_config(side))
    return hand, HandKinematics(hand.urdf_path)


def _say_verdict(name: str, coverage, reason: str) -> None:
    tqdm.write(verdict_line(name, coverage, reason))


def _status(campaign: Campaign, hand, kinematics) -> tuple[list, list[SessionSlot]]:
    records = campaign.check(hand, kinematics, progress=_say_verdict)
    return records, campaign.due(records)


def _print_due(campaign: Campaign, records: list, due: list[SessionSlot]) -> None:
    plan = campaign.plan
    total = len(plan.slots())
    print(f'{campaign.folder}: {total - len(due)} of {total} sessions done '
          f'({len(records)} bags count)')
    if not due:
        print('complete: train it with `train', campaign.folder, '--out MODELS`')
        return
    minutes = plan.duration_s(due) / 60.0
    print(f'{len(due)} due, about {minutes:.0f} min of operator time; next:')
    for slot in due[:5]:
        print(f'  press {slot.array} on the {slot.plate} plate ({plan.seconds:.0f} s)')
    print('record the next one (coverage_view shows its coverage while you press; stop it '
          f'with Ctrl-C after {plan.seconds:.0f} s):\n  ros2 launch tacforce_ros '
          f'calibration.launch.py sim:=false hand_side:={plan.hand_side} '
          f'campaign:={campaign.folder}')


def cmd_plan(args) -> int:
    hand = load_hand(hand_config(args.hand_side))
    arrays = tuple(args.arrays or [a.name for a in hand.arrays])
    unknown = sorted(set(arrays) - {a.name for a in hand.arrays})
    if unknown:
        print(f'campaign: not arrays of the hand: {unknown}', file=sys.stderr)
        return 2
    for plate in args.plates:       # a plate the rig has: its calibration scene exists
        load_scene(calibration_scene_name(arrays[0], plate))
    plan = CampaignPlan(hand_side=hand.side, arrays=arrays, plates=tuple(args.plates),
                        sessions=args.sessions, seconds=args.seconds, seed=args.seed)
    campaign = Campaign.create(args.folder, plan)
    slots = plan.slots()
    print(f'{campaign.folder / "campaign.yaml"}: {len(arrays)} arrays x {len(plan.plates)} '
          f'plates x {plan.sessions} sessions = {len(slots)} sessions of {plan.seconds:.0f} s, '
          f'about {plan.duration_s() / 3600:.1f} h of operator time (plate by plate)')
    return 0


def cmd_status(args) -> int:
    campaign = Campaign(args.folder)
    hand, kinematics = _hand_and_kinematics(campaign.plan.hand_side)
    records, due = _status(campaign, hand, kinematics)
    _print_due(campaign, records, due)
    return 0


def cmd_run(args) -> int:
    if not args.sim:
        print('campaign run: only the simulator runs sessions unattended (--sim); on the rig, '
              'record what `campaign status` says is due', file=sys.stderr)
        return 2
    from tacforce_ros.recording.sim_session import record_session
    campaign = Campaign(args.folder)
    plan = campaign.plan
    recording = campaign.folder / RECORDING
    shutil.rmtree(recording, ignore_errors=True)   # sessions interrupted: recorded again
    hand, kinematics = _hand_and_kinematics(plan.hand_side)
    records, due = _status(campaign, hand, kinematics)
    for _ in range(SIM_ROUNDS):
        if not due:
            break
        steps = sum(int(round(plan.seconds * load_scene(
            calibration_scene_name(slot.array, slot.plate)).tactile_rate)) for slot in due)
        with tqdm(total=steps, unit='step', desc=f'campaign ({len(due)} due)') as progress:
            for slot in due:
                bag = record_session(recording / slot.name, hand, slot.array, slot.plate,
                                     slot.index, plan.seconds, plan.seed, progress)
                bag.rename(campaign.folder / slot.name)
        records, due = _status(campaign, hand, kinematics)
    _print_due(campaign, records, due)
    if due:
        print(f'campaign: {len(due)} sessions still due after {SIM_ROUNDS} rounds: the '
              f'scene cannot meet the coverage limits ({campaign.folder / "rejected"} says why)',
              file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='campaign', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', required=True)
    plan = sub.add_parser('plan', help='write a campaign plan')
    plan.add_argument('folder', type=Path)
    plan.add_argument('--arrays', nargs='+', help='arrays (default: every array of the hand)')
    plan.add_argument('--plates', nargs='+', default=list(TRAINING_PLATES),
                      help='push-plates (default: the five training plates)')
    plan.add_argument('--sessions', type=int, default=2, help='sessions per array and plate')
    plan.add_argument('--seconds', type=float, default=100.0, help='length of a session [s]')
    plan.add_argument('--seed', type=int, default=0, help='simulated sessions: base seed')
    plan.add_argument('--hand-side', choices=SIDES, default='right')
    plan.set_defaults(run=cmd_plan)
    for name, run, text in (('status', cmd_status, 'judge new bags, print what is due'),
                            ('run', cmd_run, 'record what is due (simulator)')):
        command = sub.add_parser(name, help=text)
        command.add_argument('folder', type=Path)
        if name == 'run':
            command.add_argument('--sim', action='store_true', help='record in the simulator')
        command.set_defaults(run=run)
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except (CampaignError, SceneError, DatasetError, StaticSegmentError, bagio.BagError,
            OSError) as exc:
        print(f'campaign: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
