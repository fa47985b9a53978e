"""What `train` and `learning_curve` read: calibration bags, campaign folders (the bags of them
that count) and processed datasets, all of one hand, as datasets by array; and the
hyperparameters each model kind trains with from their options. Not a command itself."""
from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

from tqdm import tqdm

from tacforce_ros.estimation.dataset import CalibrationDataset
from tacforce_ros.estimation.m3_lambda import DEFAULT_GRID
from tacforce_ros.estimation.registry import TORCH_KINDS
from tacforce_ros.hand.description import (DEFAULT_SIDE, HandDescription, hand_config, load_hand,
                                           side_of)


def model_hyper(kind: str, seed: int, lambda_cv: bool, lam: float, device: str) -> dict:
    if kind in TORCH_KINDS:
        return {'seed': seed, 'device': device}
    if kind == 'M3-lambda':
        return {'lam': lam, 'lambda_grid': list(DEFAULT_GRID) if lambda_cv else None}
    return {}


def expand_campaigns(paths: list[Path], read: dict | None = None) -> list[Path]:
    """Each campaign folder replaced by the bags of it that count; other paths kept. `read`
    receives the datasets of the bags judging them read (Campaign.check)."""
    from tacforce_ros.hand.kinematics import HandKinematics
    from tacforce_ros.recording.campaign import Campaign, is_campaign, verdict_line

    expanded = []
    for path in paths:
        if not is_campaign(path):
            expanded.append(path)
            continue
        campaign = Campaign(path)
        hand = load_hand(hand_config(campaign.plan.hand_side))
        # Judged as `campaign status` judges, but the campaign is left as it is.
        records = campaign.check(hand, HandKinematics(hand.urdf_path), write=False, read=read,
                                 progress=lambda *judged: print(verdict_line(*judged),
                                                                file=sys.stderr))
        due = campaign.due(records)
        if due:
            print(f'campaign {path} is missing {len(due)} sessions (`campaign status '
                  f'{path}`); training on what it has', file=sys.stderr)
        if not records:
            raise ValueError(f'campaign {path} has no bag that counts yet (`campaign status '
                             f'{path}`)')
        expanded += campaign.counted_bags(records)
    return expanded


def load_inputs(paths: list[Path], side: str | None, read: dict | None = None
                ) -> tuple[HandDescription, dict[str, list[CalibrationDataset]], int]:
    """The hand the inputs are of (the one their bags and datasets name, all the same, or
    `side`), their datasets by array name, and the malformed messages dropped. `read`: bag
    path -> (dataset, dropped) already read (expand_campaigns), not read again."""
    from tacforce_ros.bagio import read_session_metadata
    bags = [p for p in paths if p.is_dir()]
    datasets = [CalibrationDataset.load(p) for p in paths if not p.is_dir()]
    sides = ({side_of(read_session_metadata(p).get('hand_side')) for p in bags}
             | {d.hand_side for d in datasets} | ({side} if side is not None else set()))
    if len(sides) > 1:
        raise ValueError(f'inputs of more than one hand ({sorted(sides)}): train each hand '
                         'on its own')
    hand = load_hand(hand_config(sides.pop() if sides else DEFAULT_SIDE))
    by_array: dict[str, list[CalibrationDataset]] = defaultdict(list)
    dropped = 0
    if bags:
        from tacforce_ros.estimation.bag_dataset import dataset_from_bag
        from tacforce_ros.hand.kinematics import HandKinematics
        kinematics = HandKinematics(hand.urdf_path)
        for bag in tqdm(bags, desc='bags', unit='bag'):
            dataset, n_dropped = (read or {}).get(bag) or dataset_from_bag(bag, hand, kinematics)
            by_array[dataset.array].append(dataset)
            dropped += n_dropped
    for dataset in datasets:
        by_array[dataset.array].append(dataset)
    return hand, by_array, dropped


POOL_PREFIX = 'pool:'       # a pooled array's name: POOL_PREFIX + this hand's array


def load_pool(paths: list[Path], hand: HandDescription) -> dict[str, CalibrationDataset]:
    """`--pool`: another hand's calibration (the mirror hand's campaign folders, bags or
    datasets; or a second hand of this side) in `hand`'s layout (estimation/mirror.py), one
    recording per array, named POOL_PREFIX + this hand's array of the module."""
    from tacforce_ros.estimation.dataset import concatenate
    from tacforce_ros.estimation.mirror import to_layout

    read: dict = {}
    pool_hand, by_array, _ = load_inputs(expand_campaigns(paths, read), None, read)
    if pool_hand.side == hand.side:
        print(f'pool: of the {hand.side} hand as the inputs: joined as it is, as a second '
              f'{hand.side} hand', file=sys.stderr)
    pool = {}
    for name, datasets in sorted(by_array.items()):
        if name not in {a.name for a in hand.arrays}:
            raise ValueError(f'pool: {name!r} is not an array of the {hand.side} hand')
        dataset = concatenate(datasets)
        if dataset.n_taxels != pool_hand.array(name).n_taxels:
            raise ValueError(f'pool: {name} has {dataset.n_taxels} taxels, the '
                             f'{pool_hand.side} hand\'s description '
                             f'{pool_hand.array(name).n_taxels}')
        pool[POOL_PREFIX + name] = to_layout(dataset, pool_hand.array(name), hand.array(name))
    return pool
