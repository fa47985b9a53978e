"""A hand's arrays drawn as their taxels, coloured by a figure per array (PNG, matplotlib Agg):
the per-array held-out error that `train` and the main job report."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (the backend is chosen first)
import numpy as np  # noqa: E402

from tacforce_ros.hand.kinematics import HandKinematics  # noqa: E402


def hand_errors(hand, errors: dict[str, float], title: str, path: Path) -> Path:
    """Every taxel of the hand at the URDF's zero pose (fingers straight), seen from the palm
    side (hand_root: the palm faces +x, the fingers point along +z), coloured by its array's
    error; arrays without one grey."""
    kinematics = HandKinematics(hand.urdf_path)
    fig, ax = plt.subplots(figsize=(7, 7))
    points, values = [], []
    for array in hand.arrays:
        rotation, origin = kinematics.frame_pose(np.zeros(16), array.frame_id)
        where = (array.positions @ rotation.T + origin)[:, 1:] * 1000.0     # (y, z) in mm
        points.append(where)
        values.append(np.full(len(where), errors.get(array.name, np.nan)))
        text = array.name if array.name not in errors else \
            f'{array.name}\n{errors[array.name]:.3f}'
        ax.annotate(text, where.mean(axis=0) + [0.0, 12.0], fontsize=6, ha='center')
    points, values = np.concatenate(points), np.concatenate(values)
    known = np.isfinite(values)
    ax.scatter(points[~known, 0], points[~known, 1], s=14, c='0.8')
    dots = ax.scatter(points[known, 0], points[known, 1], s=14, c=values[known], cmap='viridis')
    fig.colorbar(dots, ax=ax, label='held-out e_hat [N]', shrink=0.7)
    ax.set_aspect('equal')
    ax.set_xlabel('y [mm] (palm side view)')
    ax.set_ylabel('z [mm]')
    ax.set_title(f'{title}, {hand.side} hand')
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
