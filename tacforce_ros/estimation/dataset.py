"""Processed calibration dataset of one array: the layout both `train` and `bench` read.

X (N, n, 3) raw counts after low-pass and resampling (offsets NOT removed), F (N, 3) force [N] in
the array frame {S0} after projection (offsets NOT removed), plate label, session id (one per
recording; offsets are per session) and time [s] per sample. Stored as npz without pickle.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tacforce_ros.estimation.npz import read_npz
from tacforce_ros.estimation.preprocessing import remove_offsets
from tacforce_ros.hand.description import DEFAULT_SIDE, side_of

DATASET_FORMAT = 'tacforce-dataset/1'


class DatasetError(ValueError):
    """A dataset file or arrays that do not fit the layout."""


@dataclass(frozen=True)
class CalibrationDataset:
    array: str
    X: np.ndarray           # (N, n, 3) float64 counts
    F: np.ndarray           # (N, 3) float64 N in {S0}
    plates: np.ndarray      # (N,) str
    sessions: np.ndarray    # (N,) int64
    time: np.ndarray        # (N,) float64 s
    source: str = 'lab'     # 'lab' | 'sim' | 'synthetic'
    hand_side: str = DEFAULT_SIDE   # the hand whose array this is (its taxel order, frames)

    def __post_init__(self) -> None:
        n = self.X.shape[0]
        if self.X.ndim != 3 or self.X.shape[2] != 3:
            raise DatasetError(f'X must be (N, n, 3), got {self.X.shape}')
        for name, shape in (('F', (n, 3)), ('plates', (n,)), ('sessions', (n,)),
                            ('time', (n,))):
            if getattr(self, name).shape != shape:
                raise DatasetError(f'{name} has shape {getattr(self, name).shape}, '
                                   f'expected {shape}')
        if not (np.all(np.isfinite(self.X)) and np.all(np.isfinite(self.F))):
            raise DatasetError('X or F contains NaN or Inf')

    @property
    def n_taxels(self) -> int:
        return int(self.X.shape[1])

    def plate_names(self) -> list[str]:
        return list(dict.fromkeys(self.plates.tolist()))

    def without_offsets(self, **static_kw) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X, F, mean taxel offset): each session's static offsets subtracted."""
        F, X, offsets = remove_offsets(self.F, self.X, self.sessions, **static_kw)
        return X, F, np.mean([o.taxels for o in offsets.values()], axis=0)

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        header = {'format': DATASET_FORMAT, 'array': self.array, 'source': self.source,
                  'hand_side': self.hand_side}
        with path.open('wb') as stream:
            np.savez_compressed(stream, header=np.array(json.dumps(header)), X=self.X, F=self.F,
                                plates=self.plates.astype(str), sessions=self.sessions,
                                time=self.time)
        return path

    @classmethod
    def load(cls, path: str | Path) -> CalibrationDataset:
        try:
            data = read_npz(path)
            header = json.loads(str(data['header']))
        except FileNotFoundError:
            raise DatasetError(f'{path}: no such dataset file') from None
        except (ValueError, KeyError) as exc:
            raise DatasetError(f'{path}: not a readable dataset file ({exc})') from None
        if header.get('format') != DATASET_FORMAT:
            raise DatasetError(f'{path}: format {header.get("format")!r}, '
                               f'expected {DATASET_FORMAT!r}')
        missing = {'X', 'F', 'plates', 'sessions', 'time'} - set(data)
        if missing:
            raise DatasetError(f'{path}: missing entries {sorted(missing)}')
        return cls(array=header['array'], X=data['X'].astype(np.float64),
                   F=data['F'].astype(np.float64), plates=data['plates'].astype(str),
                   sessions=data['sessions'].astype(np.int64),
                   time=data['time'].astype(np.float64), source=header.get('source', 'lab'),
                   hand_side=side_of(header.get('hand_side')))


def concatenate(parts: list[CalibrationDataset]) -> CalibrationDataset:
    """Join recordings of the same array; session ids are renumbered to stay distinct."""
    if not parts:
        raise DatasetError('no recordings to join')
    names = {p.array for p in parts}
    if len(names) != 1:
        raise DatasetError(f'recordings of different arrays cannot be joined: {sorted(names)}')
    sides = {p.hand_side for p in parts}
    if len(sides) != 1:
        raise DatasetError(f'recordings of both hands cannot be joined: {sorted(sides)}')
    sessions, next_id = [], 0
    for part in parts:
        _, ids = np.unique(part.sessions, return_inverse=True)
        sessions.append(ids + next_id)
        next_id += int(ids.max()) + 1 if ids.size else 0
    sources = {p.source for p in parts}
    return CalibrationDataset(
        array=parts[0].array, X=np.concatenate([p.X for p in parts]),
        F=np.concatenate([p.F for p in parts]), plates=np.concatenate([p.plates for p in parts]),
        sessions=np.concatenate(sessions), time=np.concatenate([p.time for p in parts]),
        source=sources.pop() if len(sources) == 1 else 'mixed', hand_side=sides.pop())
