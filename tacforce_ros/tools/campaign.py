"""campaign: plan, check and run a calibration campaign over the arrays of the whole hand.

    campaign plan FOLDER [--arrays ...] [--plates ...] [--sessions N] [--seconds S]
        writes FOLDER/campaign.yaml and prints the sessions in recording order with the time
        they take (default: all 18 arrays, the five training plates, 2 x 100 s each).
    campaign plan FOLDER --budget 60m --curves learning_curve.json
        a plan with at most that much pressing: one session per array and plate, the session
        length of each kind of array chosen to minimise the whole hand's expected held-out
        error (recording/budget.py), read off kind curves (`learning_curve --kind-curve`, or
        the main job's report.json). `train FOLDER --out MODELS` then trains shared models.
    campaign status FOLDER
        judges every bag not yet judged (force range, shear directions, rests), moves a poor one
        to FOLDER/rejected/ with the reasons, and prints what counts and what is due; a budget
        plan's status adds each array's expected held-out error from what it has. On the
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
import json
import shutil
import sys
from pathlib import Path

from tqdm import tqdm

from tacforce_ros import bagio
from tacforce_ros.estimation.dataset import DatasetError
from tacforce_ros.rig import TRAINING_PLATES
from tacforce_ros.estimation.preprocessing import StaticSegmentError
from tacforce_ros.hand.description import SIDES, hand_config, load_hand
from tacforce_ros.recording.budget import (MIN_SESSION_S, RESERVE, BudgetError, ExpectedError,
                                           allocate, parse_budget)
from tacforce_ros.recording.campaign import (Campaign, CampaignError, CampaignPlan, SessionSlot,
                                             verdict_line)
from tacforce_ros.rig import RATE_HZ
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
    print(f'{len(due)} due, {plan.pressing_s(due) / 60:.0f} min of pressing, about '
          f'{minutes:.0f} min of operator time; next:')
    for slot in due[:5]:
        print(f'  press {slot.array} on the {slot.plate} plate '
              f'({plan.session_seconds(slot.array):.0f} s)')
    print('record the next one (coverage_view shows its coverage while you press; stop it '
          f'with Ctrl-C after {plan.session_seconds(due[0].array):.0f} s):\n'
          '  ros2 launch tacforce_ros '
          f'calibration.launch.py sim:=false hand_side:={plan.hand_side} '
          f'campaign:={campaign.folder}')


def _expected_of(path: Path) -> ExpectedError:
    """Kind curves from a learning_curve.json (`rows`) or a main job's report.json
    (`budget_campaign.kind_curve_rows`)."""
    try:
        doc = json.loads(path.read_text())
        # learning_curve.json's rows, or a main job's kind curves (report.json).
        rows = doc['rows'] if 'rows' in doc else doc['budget_campaign']['kind_curve_rows']
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BudgetError(f'--curves {path}: no learning-curve rows ({exc})') from None
    commit = (doc.get('provenance') or doc.get('run') or {}).get('code_version', '')
    return ExpectedError.from_rows(rows, f'{path.name}' + (f' at {commit}' if commit else ''))


def cmd_plan(args) -> int:
    hand = load_hand(hand_config(args.hand_side))
    arrays = tuple(args.arrays or [a.name for a in hand.arrays])
    unknown = sorted(set(arrays) - {a.name for a in hand.arrays})
    if unknown:
        print(f'campaign: not arrays of the hand: {unknown}', file=sys.stderr)
        return 2
    for plate in args.plates:       # a plate the rig has: its calibration scene exists
        load_scene(calibration_scene_name(arrays[0], plate))
    budgeted = {}
    if args.budget is not None:
        if args.sessions is not None or args.seconds is not None:
            print('campaign: --budget chooses the sessions and their lengths; leave out '
                  '--sessions and --seconds', file=sys.stderr)
            return 2
        args.min_session = MIN_SESSION_S if args.min_session is None else args.min_session
        args.reserve = RESERVE if args.reserve is None else args.reserve
        budget_s = parse_budget(args.budget)
        expected = _expected_of(args.curves)
        kinds = {}
        for name in arrays:
            kinds[hand.array(name).kind] = kinds.get(hand.array(name).kind, 0) + 1
        few = {k: n for k, n in kinds.items() if n < 3}
        if few and not expected.pooled:
            raise BudgetError(f'a budget plan gives each array the model its kind shares, which '
                              f'needs three or more arrays of the kind; the plan has {few} (or '
                              'plan on kind curves made with the other hand\'s pool, '
                              '`learning_curve --kind-curve --pool`)')
        allocation = allocate(budget_s, kinds, len(args.plates), expected, args.min_session,
                              args.reserve)
        budgeted = {'durations': {a: allocation.session_s[hand.array(a).kind] for a in arrays},
                    'budget': {'budget_s': budget_s, 'min_session_s': args.min_session,
                               'reserve': args.reserve,
                               'expected': expected.to_dict()},
                    'sessions': 1, 'seconds': max(allocation.session_s.values())}
    elif args.min_session is not None or args.reserve is not None:
        print('campaign: --min-session and --reserve go with --budget', file=sys.stderr)
        return 2
    plan = CampaignPlan(**{'hand_side': hand.side, 'arrays': arrays, 'plates': tuple(args.plates),
                           'sessions': args.sessions or 2, 'seconds': args.seconds or 100.0,
                           'seed': args.seed, **budgeted})
    campaign = Campaign.create(args.folder, plan)
    slots = plan.slots()
    if not budgeted:
        print(f'{campaign.folder / "campaign.yaml"}: {len(arrays)} arrays x '
              f'{len(plan.plates)} plates x {plan.sessions} sessions = {len(slots)} sessions of '
              f'{plan.seconds:.0f} s, about {plan.duration_s() / 3600:.1f} h of operator time '
              '(plate by plate)')
        return 0
    print(f'{campaign.folder / "campaign.yaml"}: {len(arrays)} arrays x {len(plan.plates)} '
          f'plates, one session each: {plan.pressing_s() / 60:.0f} min of pressing (budget '
          f'{budget_s / 60:.0f} min, {100 * args.reserve:.0f} % of it held back for sessions '
          f'pressed again), about {plan.duration_s() / 3600:.1f} h of operator time; '
          f'expected error from {expected.source}')
    print('| kind | arrays | session [s] | per array [s] | expected e_hat [N] |\n'
          '|---|---|---|---|---|')
    for kind, n in allocation.arrays.items():
        length = allocation.session_s[kind]
        print(f'| {kind} | {n} | {length:.0f} | {length * len(plan.plates):.0f} | '
              f'{allocation.expected_e_hat[kind]:.3f} |')
    pool = ' --pool POOL' if expected.pooled else ''
    print(f'whole hand: expected e_hat {allocation.mean_e_hat:.3f} N (mean over arrays); train '
          f'it with `train {campaign.folder} --out MODELS{pool}` (shared models, as --shared'
          + (', with the pool its curves had' if pool else '') + ')')
    return 0


def expected_lines(campaign: Campaign, records: list, hand) -> list[str]:
    """A budget plan's expected held-out e_hat per array from the seconds it has counted."""
    plan = campaign.plan
    if not plan.budget:
        return []
    expected = ExpectedError.from_dict(plan.budget['expected'])
    trained = {path.name for path in campaign.counted_bags(records)}
    counted: dict[str, float] = {}
    for record in records:
        if record.bag in trained:       # a bag past the plan's sessions is not trained on
            counted[record.array] = counted.get(record.array, 0.0) + \
                record.coverage['samples'] / RATE_HZ
    lines = ['| array | kind | pressed [s] | planned [s] | expected e_hat [N] |',
             '|---|---|---|---|---|']
    for name in plan.arrays:
        kind = hand.array(name).kind
        have = counted.get(name, 0.0)
        if have > 0:
            value, side = expected.expected(kind, have)
            cell = {0: f'{value:.3f}', -1: f'>= {value:.3f} (below the curve)',
                    1: f'<= {value:.3f} (beyond the curve)'}[side]
        else:
            cell = 'none yet'
        planned = plan.session_seconds(name) * plan.sessions * len(plan.plates)
        lines.append(f'| {name} | {kind} | {have:.0f} | {planned:.0f} | {cell} |')
    return lines


def cmd_status(args) -> int:
    campaign = Campaign(args.folder)
    hand, kinematics = _hand_and_kinematics(campaign.plan.hand_side)
    records, due = _status(campaign, hand, kinematics)
    for line in expected_lines(campaign, records, hand):
        print(line)
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
        steps = sum(int(round(plan.session_seconds(slot.array) * load_scene(
            calibration_scene_name(slot.array, slot.plate)).tactile_rate)) for slot in due)
        with tqdm(total=steps, unit='step', desc=f'campaign ({len(due)} due)') as progress:
            for slot in due:
                bag = record_session(recording / slot.name, hand, slot.array, slot.plate,
                                     slot.index, plan.session_seconds(slot.array), plan.seed,
                                     progress)
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
    plan.add_argument('--sessions', type=int, help='sessions per array and plate (default 2)')
    plan.add_argument('--seconds', type=float, help='length of a session [s] (default 100)')
    plan.add_argument('--seed', type=int, default=0, help='simulated sessions: base seed')
    plan.add_argument('--budget', help='pressing time to plan for (60m, 1.5h, 3600s): one '
                      'session per array and plate, lengths chosen per kind of array')
    plan.add_argument('--curves', type=Path, help='with --budget: kind curves '
                      '(learning_curve.json of `learning_curve --kind-curve`, or report.json)')
    plan.add_argument('--min-session', type=float,
                      help=f'with --budget: shortest session [s] (default {MIN_SESSION_S:g})')
    plan.add_argument('--reserve', type=float,
                      help=f'with --budget: share held back for sessions pressed again '
                           f'(default {RESERVE:g})')
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
    if args.command == 'plan' and (args.budget is None) != (args.curves is None):
        parser.error('--budget and --curves go together (the curves say what each second buys)')
    try:
        return args.run(args)
    except (CampaignError, BudgetError, SceneError, DatasetError, StaticSegmentError,
            bagio.BagError, OSError) as exc:
        print(f'campaign: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
