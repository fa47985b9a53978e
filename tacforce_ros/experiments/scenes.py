"""Scene variants the experiments run, written as scene files so both paths load the same one.

Closed-loop runs start from a zeroed F/T sensor, as the lab zeroes it with nothing on the plate
before each run (the paper treats the F/T reading as unbiased ground truth). The closed-loop
scenes keep the finger on the plate from t = 0, so there is no moment to zero it in the run
itself; the variant switches off the effect's un-zeroed bias draw and keeps its noise and drift.
"""
from __future__ import annotations

from pathlib import Path

import yaml

ZEROED_FT = {'ft_noise': {'force_bias_sigma': 0.0, 'torque_bias_sigma': 0.0}}


def zeroed_ft_scene(scene_name: str, folder: Path) -> Path:
    """Write `<folder>/<scene_name>_zeroed_ft.yaml` extending the project scene; return it."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f'{scene_name}_zeroed_ft.yaml'
    text = ('# Written by reproduce (experiments/scenes.py): F/T zeroed before the run.\n'
            + yaml.safe_dump({'extends': scene_name, 'effects': ZEROED_FT}, sort_keys=False))
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)
    return path
