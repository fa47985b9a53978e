"""Trained model bundles and their files: npz arrays + a JSON header, no pickle.

A bundle is everything needed to turn raw counts of one array into newtons in {S0}: the model,
the input/output standardisation, the default tare (taxel offsets) and the provenance.

File layout (np.savez, loaded with allow_pickle=False):
  header          0-d unicode array: JSON with format, array, hand_side, n_taxels, module_code,
                  kind, hyperparameters, provenance and the sha256 of every other entry
  x_mean x_std x_dead f_mean f_std f_dead x_offset   standardisation and tare
  state.<name>    the model's state_arrays()
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tacforce_ros.estimation.base import ForceModel
from tacforce_ros.estimation.npz import read_npz
from tacforce_ros.estimation.preprocessing import Standardiser

if TYPE_CHECKING:
    from tacforce_ros.hand.description import TaxelArray

FORMAT = 'tacforce-model/1'
PROVENANCE_KEYS = ('dataset', 'plates', 'samples', 'date', 'seed', 'code_version', 'metrics')
_STATE_PREFIX = 'state.'


class ModelFileError(ValueError):
    """A model file that is unreadable, corrupted or made for something else."""


@dataclass
class ModelBundle:
    model: ForceModel
    x_scaler: Standardiser          # over (n, 3) taxel channels, counts after tare
    f_scaler: Standardiser          # over the 3 force axes, N
    x_offset: np.ndarray            # (n, 3) default tare [counts]
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def array(self) -> TaxelArray:
        return self.model.array

    def predict(self, counts: np.ndarray, tare: np.ndarray | None = None) -> np.ndarray:
        """Raw counts (N, n, 3) -> force (N, 3) [N] in {S0}; tare defaults to x_offset."""
        tare = self.x_offset if tare is None else tare
        X = self.x_scaler.transform(np.asarray(counts, dtype=np.float64) - tare)
        return self.f_scaler.inverse(self.model.predict(X))


def _sha256(array: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(array).tobytes()).hexdigest()


def save_model(path: str | Path, bundle: ModelBundle) -> Path:
    """Write a bundle; refuses provenance without the required keys."""
    missing = [key for key in PROVENANCE_KEYS if key not in bundle.provenance]
    if missing:
        raise ValueError(f'provenance lacks {missing}; required: {list(PROVENANCE_KEYS)}')
    array = bundle.array
    arrays = {
        'x_mean': bundle.x_scaler.mean, 'x_std': bundle.x_scaler.std,
        'x_dead': bundle.x_scaler.dead, 'f_mean': bundle.f_scaler.mean,
        'f_std': bundle.f_scaler.std, 'f_dead': bundle.f_scaler.dead,
        'x_offset': np.asarray(bundle.x_offset, dtype=np.float64),
    }
    arrays.update({_STATE_PREFIX + k: np.asarray(v)
                   for k, v in bundle.model.state_arrays().items()})
    header = {
        'format': FORMAT, 'array': array.name, 'hand_side': array.hand_side,
        'n_taxels': int(array.n_taxels),
        'module_code': array.module_code, 'kind': bundle.model.kind,
        'hyperparameters': bundle.model.hyperparameters(), 'provenance': bundle.provenance,
        'sha256': {key: _sha256(value) for key, value in arrays.items()},
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open('wb') as stream:
        np.savez(stream, header=np.array(json.dumps(header, sort_keys=True)), **arrays)
    return path


def read_header(path: str | Path) -> dict[str, Any]:
    """The JSON header of a model file (cheap: reads no weights)."""
    return _open(Path(path))[0]


def _open(path: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    try:
        arrays = read_npz(path)
    except FileNotFoundError:
        raise ModelFileError(f'{path}: no such model file') from None
    except ValueError as exc:
        raise ModelFileError(f'{path}: not a readable npz model file ({exc})') from None
    if 'header' not in arrays:
        raise ModelFileError(f'{path}: no header entry; not a tacforce model file')
    try:
        header = json.loads(str(arrays.pop('header')))
    except json.JSONDecodeError as exc:
        raise ModelFileError(f'{path}: header is not valid JSON ({exc})') from None
    if header.get('format') != FORMAT:
        raise ModelFileError(f'{path}: format {header.get("format")!r}, expected {FORMAT!r}')
    return header, arrays


def load_model(path: str | Path, array: TaxelArray) -> ModelBundle:
    """Load a bundle for `array`; every mismatch is refused with what differs."""
    from tacforce_ros.estimation.registry import model_class
    from tacforce_ros.hand.description import side_of

    path = Path(path)
    header, arrays = _open(path)
    for key in ('array', 'n_taxels', 'kind', 'hyperparameters', 'provenance', 'sha256'):
        if key not in header:
            raise ModelFileError(f'{path}: header lacks {key!r}')
    if header['array'] != array.name:
        raise ModelFileError(f'{path}: model is for array {header["array"]!r}, '
                             f'not {array.name!r}')
    side = side_of(header.get('hand_side'))     # none: written before the left hand existed
    if side != array.hand_side:
        raise ModelFileError(f'{path}: model is for the {side} hand\'s {header["array"]}, not '
                             f'the {array.hand_side} hand\'s (a mirror image: its taxels are '
                             'elsewhere)')
    if header['n_taxels'] != array.n_taxels:
        raise ModelFileError(f'{path}: model has {header["n_taxels"]} taxels, array '
                             f'{array.name!r} has {array.n_taxels}')
    try:
        cls = model_class(header['kind'])
    except ValueError as exc:
        raise ModelFileError(f'{path}: {exc}') from None
    expected = set(header['sha256'])
    if set(arrays) != expected:
        raise ModelFileError(f'{path}: entries {sorted(set(arrays) ^ expected)} missing or '
                             'unexpected')
    for key, digest in header['sha256'].items():
        if _sha256(arrays[key]) != digest:
            raise ModelFileError(f'{path}: entry {key!r} is corrupted (checksum mismatch)')
    for key, value in arrays.items():
        # A checksum only proves the file is as written: a training that diverged writes NaNs
        # with a matching checksum, and a model with them estimates NaN forever.
        if value.dtype.kind in 'fc' and not np.all(np.isfinite(value)):
            bad = int(np.count_nonzero(~np.isfinite(value)))
            raise ModelFileError(f'{path}: entry {key!r} holds {bad} of {value.size} values '
                                 'NaN or Inf; refusing the model')
    state = {k[len(_STATE_PREFIX):]: v for k, v in arrays.items() if k.startswith(_STATE_PREFIX)}
    try:
        model = cls.from_state(array, header['hyperparameters'], state)
        x_scaler = Standardiser(arrays['x_mean'], arrays['x_std'], arrays['x_dead'])
        f_scaler = Standardiser(arrays['f_mean'], arrays['f_std'], arrays['f_dead'])
    except (KeyError, ValueError, TypeError) as exc:
        raise ModelFileError(f'{path}: {exc}') from None
    shapes = {'x_mean': (array.n_taxels, 3), 'x_std': (array.n_taxels, 3),
              'x_offset': (array.n_taxels, 3), 'f_mean': (3,), 'f_std': (3,)}
    for key, shape in shapes.items():
        if arrays[key].shape != shape:
            raise ModelFileError(f'{path}: {key} has shape {arrays[key].shape}, expected {shape}')
    return ModelBundle(model=model, x_scaler=x_scaler, f_scaler=f_scaler,
                       x_offset=arrays['x_offset'], provenance=header['provenance'])
