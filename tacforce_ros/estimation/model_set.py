"""The estimator's models: a YAML listing one model file per array (mixed kinds allowed), loaded
into one RuntimeEstimator over just the arrays that have a model.

    models:                      # paths relative to this file (or absolute)
      index_tip: index_tip_M3-lambda.npz
      index_middle: index_middle_M4.npz

RuntimeEstimator needs one model per array of the hand it is given, so arrays without a model
are left out of a sub-hand whose flat taxel indices are renumbered; `estimate()` gathers their
taxels from the full frame first. Pure numpy (no rclpy): the node only wires it.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from tacforce_ros.estimation.model_io import ModelFileError, load_model, save_model
from tacforce_ros.estimation.npz import read_npz
from tacforce_ros.estimation.runtime import HandEstimate, RuntimeEstimator
from tacforce_ros.estimation.taxel_health import (FROZEN_FRAMES, OUT_OF_RANGE, OUT_OF_RANGE_KIND,
                                                  TaxelFault, TaxelHealth, fault_status)
from tacforce_ros.hand.description import HandDescription
from tacforce_ros.paths import config_dir


class ModelConfigError(ValueError):
    """A model list that cannot be used; the message names the file and the entry."""


@dataclass
class ModelSet:
    estimator: RuntimeEstimator
    arrays: tuple                  # the modelled TaxelArrays, hand order (original indices)
    skipped: tuple[str, ...]       # hand arrays without a model
    taxels: np.ndarray             # flat indices (of the full frame) the sub-hand reads
    kinds: tuple[str, ...]

    # Taxel health (estimation/taxel_health.py), off until check_taxels() (the estimator node
    # and the in-process closed loop switch it on); out_of_range is the |z| beyond which an
    # array's input is far outside its calibration (inf: never).
    health: TaxelHealth | None = None
    out_of_range: float = OUT_OF_RANGE

    def __post_init__(self) -> None:
        # Every array modelled: the sub-hand is the hand, and the per-tick gather is skipped.
        self._whole_hand = not self.skipped
        sub_hand = self.estimator.hand
        self._array_of_taxel = np.empty(sub_hand.n_taxels, dtype=np.intp)
        self._index_in_array = np.empty(sub_hand.n_taxels, dtype=np.intp)
        for k, array in enumerate(sub_hand.arrays):
            self._array_of_taxel[array.flat_indices] = k
            self._index_in_array[array.flat_indices] = np.arange(array.n_taxels)

    def check_taxels(self, frozen_frames: int | None = FROZEN_FRAMES,
                     out_of_range: float = OUT_OF_RANGE) -> None:
        """Flag arrays with a clipped, frozen or far out-of-range taxel from now on (None
        frames: frozen taxels not looked for; out_of_range inf: nor far ones)."""
        self.health = TaxelHealth(self.estimator.hand.n_taxels, frozen_frames)
        self.out_of_range = out_of_range

    def estimate(self, counts: np.ndarray) -> HandEstimate:
        """Full-hand flat counts (n_taxels, 3) -> estimates of the modelled arrays; with the
        taxel check on, an array with a faulty taxel is invalid, its status naming the taxel."""
        counts = np.asarray(counts)
        if self._whole_hand or counts.ndim != 2 or counts.shape[0] <= int(self.taxels[-1]):
            sub = counts            # the estimator's own message names a wrong shape
        else:
            sub = counts[self.taxels]
        estimate = self.estimator.estimate(sub)
        if self.health is None or sub.shape != (self.health.n_taxels, 3):
            return estimate
        faults = self.health.check(sub)
        far = estimate.ood_score > self.out_of_range        # inf (no finite input) is flagged
        if faults or far.any():
            return self._flag(estimate, faults, far)
        return estimate

    def _flag(self, estimate: HandEstimate, faults: list[TaxelFault],
              far: np.ndarray) -> HandEstimate:
        status, valid = list(estimate.status), estimate.valid.copy()
        force = estimate.force.copy()
        for fault in faults:
            k = int(self._array_of_taxel[fault.taxel])
            if valid[k]:            # the first fault of an array names it
                status[k] = fault_status(fault, int(self._index_in_array[fault.taxel]))
                valid[k] = False
        for k in np.flatnonzero(far & valid):
            # no figure in the status (the OOD score carries it): statuses stay few
            status[k] = fault_status(TaxelFault(-1, OUT_OF_RANGE_KIND),
                                     self.estimator.worst_taxel(int(k)))
            valid[k] = False
        force[~valid] = 0.0
        return HandEstimate(force=force, valid=valid, status=tuple(status),
                            ood_score=estimate.ood_score)

    def set_tare(self, frames: np.ndarray) -> None:
        """Tare every modelled array from full-hand no-contact frames (T, n_taxels, 3)."""
        frames = np.asarray(frames)
        self.estimator.set_tare(frames if self._whole_hand else frames[:, self.taxels])

    def save_tare(self, path: str | Path) -> None:
        """The current tare of every modelled array to a .npz (one (n, 3) counts entry per
        array), replaced whole: a process killed while writing leaves the previous file."""
        path = Path(path)
        partial = path.with_name(path.name + '.partial')
        with open(partial, 'wb') as file:
            np.savez(file, **{a.name: self.estimator.tare(a.name) for a in self.arrays})
        os.replace(partial, path)

    def load_tare(self, path: str | Path) -> None:
        """The tare of every modelled array from a file of save_tare(); ValueError saying why
        when it does not fit these arrays (FileNotFoundError when it is absent)."""
        entries = read_npz(path)
        sub_hand = self.estimator.hand
        frame = np.zeros((sub_hand.n_taxels, 3))
        for array in sub_hand.arrays:
            tare = entries.get(array.name)
            if tare is None:
                raise ValueError(f'{path}: no tare for {array.name}')
            if tare.shape != (array.n_taxels, 3) or not np.all(np.isfinite(tare)):
                raise ValueError(f'{path}: the tare of {array.name} is not {array.n_taxels} x 3 '
                                 f'finite counts (shape {tare.shape})')
            frame[array.flat_indices] = tare
        self.estimator.set_tare(frame[None])


def model_files(path: str | Path) -> dict[str, Path]:
    """The model file of each array a models YAML lists, relative paths resolved."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ModelConfigError(f'{path}: {exc}') from None
    models = (doc or {}).get('models') if isinstance(doc, dict) else None
    if not isinstance(models, dict) or not models:
        raise ModelConfigError(f'{path}: needs a non-empty "models" mapping array -> file')
    files = {str(name): Path(str(file)) for name, file in models.items()}
    return {name: file if file.is_absolute() else path.parent / file
            for name, file in files.items()}


def write_model_config(path: str | Path, models: dict[str, str], comment: str = '') -> Path:
    """A models YAML listing `models` (array -> file, relative to the YAML), with `comment`
    lines on top."""
    path = Path(path)
    head = ''.join(f'# {line}\n' for line in comment.splitlines())
    path.write_text(head + yaml.safe_dump({'models': models}, sort_keys=False))
    return path


def default_model_config(hand: HandDescription) -> Path:
    """The shipped models YAML of a hand: config/models/default.yaml for the right hand,
    config/models/<side>/default.yaml for another (its models are trained on that hand)."""
    models = config_dir() / 'models'
    return models / 'default.yaml' if hand.side == 'right' else models / hand.side / 'default.yaml'


def load_model_set(path: str | Path, hand: HandDescription) -> ModelSet:
    path = Path(path)
    models = model_files(path)
    names = {a.name for a in hand.arrays}
    unknown = sorted(set(models) - names)
    if unknown:
        raise ModelConfigError(f'{path}: unknown arrays {unknown}; the hand has {sorted(names)}')
    modelled = tuple(a for a in hand.arrays if a.name in models)
    bundles = []
    for array in modelled:
        try:
            bundles.append(load_model(models[array.name], array))
        except (ModelFileError, OSError) as exc:
            raise ModelConfigError(f'{path}: models.{array.name}: {exc}') from None
    taxels = np.sort(np.concatenate([a.flat_indices for a in modelled]))
    sub_arrays = tuple(dataclasses.replace(a, flat_indices=np.searchsorted(taxels, a.flat_indices))
                       for a in modelled)
    sub_hand = dataclasses.replace(hand, arrays=sub_arrays)
    try:
        estimator = RuntimeEstimator(sub_hand, bundles)
    except ValueError as exc:
        raise ModelConfigError(f'{path}: {exc}') from None
    return ModelSet(estimator=estimator, arrays=modelled,
                    skipped=tuple(a.name for a in hand.arrays if a.name not in models),
                    taxels=taxels, kinds=estimator.kinds)


def write_synthetic_model_set(folder: str | Path, hand: HandDescription,
                              use: dict[str, Path] | None = None) -> Path:
    """A models YAML with an M3 model per array fitted on SYNTHETIC data (estimation/synthetic),
    for tests and benchmarks that need a real model file on every array but not accuracy;
    `use` names existing model files for some arrays. Returns the YAML path."""
    from tacforce_ros.estimation.synthetic import synthetic_dataset
    from tacforce_ros.estimation.training import fit_bundle

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    models = {}
    for k, array in enumerate(hand.arrays):
        if use and array.name in use:
            models[array.name] = str(use[array.name])
            continue
        data = synthetic_dataset(array, plates=('flat', 'button'), seconds=4.0, seed=k)
        rest = data.X[:20].mean(axis=0)       # the recordings start at rest
        provenance = {'dataset': ['synthetic'], 'plates': ['flat', 'button'],
                      'samples': int(data.X.shape[0]), 'date': '', 'seed': k,
                      'code_version': 'synthetic', 'metrics': None}
        bundle = fit_bundle(array, 'M3', {}, data.X - rest, data.F, data.plates,
                            x_offset=rest, provenance=provenance)
        models[array.name] = save_model(folder / f'{array.name}_M3.npz', bundle).name
    return write_model_config(folder / 'models.yaml', models)


class TareWindow:
    """Untouched tactile frames gathered for a tare, as the estimator node's ~/tare and the
    in-process closed loop both take them: add() each frame, take() the stack (T, n, 3) float64
    to ModelSet.set_tare. The node tares once `size` frames are in; the closed loop at the end
    of its settling hold on those it has."""

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f'a tare needs at least one frame, not {size}')
        self.size = size
        self._frames: list[np.ndarray] = []

    def add(self, counts: np.ndarray) -> bool:
        """One frame (n_taxels, 3); True once the window holds `size` frames."""
        self._frames.append(np.array(counts, dtype=np.float64))     # a copy: buffers get reused
        return len(self._frames) >= self.size

    def take(self) -> np.ndarray:
        """The frames gathered, emptying the window; ValueError when there are none."""
        if not self._frames:
            raise ValueError('no frames to tare on')
        frames, self._frames = np.stack(self._frames), []
        return frames
