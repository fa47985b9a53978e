"""Error metrics of the paper (Sec. V-A, eqs. 7-8), in newtons in the array frame {S0}."""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

MIN_RELATIVE_FORCE = 0.5    # N; |f_i| below this is excluded from e_r (paper Sec. V-A)


@dataclass(frozen=True)
class ErrorStats:
    """Mean and std over samples; e_r_* are None when no sample has |f_i| >= the threshold."""

    e_r_mean: float | None      # relative error, fraction (x100 for %)
    e_r_std: float | None
    e_r_samples: int            # samples with at least one axis counted in e_r
    e_hat_mean: float           # mean absolute error [N]
    e_hat_std: float
    mae_axis: tuple[float, float, float]    # per-axis MAE [N]: x, y shear; z normal in {S0}
    samples: int

    def as_dict(self) -> dict:
        return asdict(self)


def error_stats(true: np.ndarray, pred: np.ndarray,
                min_force: float = MIN_RELATIVE_FORCE) -> ErrorStats:
    """e_r = mean over counted axes |(f_i - f^_i) / f_i|, e^ = mean over axes |f_i - f^_i|."""
    true = np.asarray(true, dtype=np.float64)
    pred = np.asarray(pred, dtype=np.float64)
    if true.shape != pred.shape or true.ndim != 2 or true.shape[1] != 3 or true.shape[0] == 0:
        raise ValueError(f'need matching non-empty (N, 3) forces, got {true.shape}, {pred.shape}')
    if not (np.all(np.isfinite(true)) and np.all(np.isfinite(pred))):
        raise ValueError('forces contain NaN or Inf')
    abs_err = np.abs(true - pred)
    counted = np.abs(true) >= min_force
    # Division only where counted, so tiny forces never produce inf.
    rel = np.divide(abs_err, np.abs(true), out=np.zeros_like(abs_err), where=counted)
    n_axes = counted.sum(axis=1)
    rows = n_axes > 0
    per_sample_rel = rel[rows].sum(axis=1) / n_axes[rows]
    per_sample_abs = abs_err.mean(axis=1)
    return ErrorStats(
        e_r_mean=float(per_sample_rel.mean()) if rows.any() else None,
        e_r_std=float(per_sample_rel.std()) if rows.any() else None,
        e_r_samples=int(rows.sum()),
        e_hat_mean=float(per_sample_abs.mean()),
        e_hat_std=float(per_sample_abs.std()),
        mae_axis=tuple(float(v) for v in abs_err.mean(axis=0)),
        samples=int(true.shape[0]))


def average_folds(folds: list[ErrorStats]) -> dict:
    """Fold means and stds averaged over folds, as the paper reports (Table I)."""
    def mean_of(values):
        values = [v for v in values if v is not None]
        return float(np.mean(values)) if values else None

    return {
        'e_r_mean': mean_of([f.e_r_mean for f in folds]),
        'e_r_std': mean_of([f.e_r_std for f in folds]),
        'e_hat_mean': mean_of([f.e_hat_mean for f in folds]),
        'e_hat_std': mean_of([f.e_hat_std for f in folds]),
        'mae_axis': [float(v) for v in np.mean([f.mae_axis for f in folds], axis=0)],
        'folds': len(folds),
    }
