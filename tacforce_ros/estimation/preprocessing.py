"""Signal processing of calibration recordings (paper Sec. IV-A, steps 1-5), one function per step.

(1) zero-phase low-pass, (2) resampling onto the tactile time base, (3) projection of the measured
force into the array frame {S0}, (4) offsets from static no-contact segments, (5) standardisation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

from tacforce_ros.rig import RATE_HZ

SAMPLE_RATE_HZ = RATE_HZ    # the tactile frames' rate, the recording rate of the paper
CUTOFF_HZ = 10.0            # paper Sec. IV-A


class StaticSegmentError(ValueError):
    """No static (no-contact) segment found, so offsets cannot be estimated."""


# --- (1) low-pass -------------------------------------------------------------------------------

def lowpass(signal: np.ndarray, fs: float = SAMPLE_RATE_HZ, cutoff: float = CUTOFF_HZ,
            order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth low-pass along axis 0 (forward-backward, so no delay)."""
    signal = np.asarray(signal, dtype=np.float64)
    if not 0.0 < cutoff < fs / 2.0:
        raise ValueError(f'cut-off {cutoff} Hz must lie in (0, {fs / 2.0}) Hz for fs = {fs} Hz')
    if not np.all(np.isfinite(signal)):
        raise ValueError('low-pass input contains NaN or Inf')
    sos = butter(order, cutoff, btype='low', fs=fs, output='sos')
    # sosfiltfilt pads each end with padlen samples (its default, reproduced here to check it).
    trailing_zeros = min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
    padlen = 3 * (2 * len(sos) + 1 - trailing_zeros)
    if signal.shape[0] <= padlen:
        raise ValueError(f'low-pass needs more than {padlen} samples '
                         f'({padlen / fs:.2f} s at {fs} Hz), got {signal.shape[0]}')
    return sosfiltfilt(sos, signal, axis=0)


# --- (2) resampling ------------------------------------------------------------------------------

def common_span(*times: np.ndarray) -> tuple[float, float]:
    """Interval covered by every stream (start, stop); refuses streams that do not overlap."""
    start = max(float(np.min(t)) for t in times)
    stop = min(float(np.max(t)) for t in times)
    if not stop > start:
        raise ValueError(f'streams do not overlap in time (latest start {start:.3f} s, '
                         f'earliest end {stop:.3f} s)')
    return start, stop


def resample(base_time: np.ndarray, time: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of `values` (M, ...) stamped `time` (M,) onto `base_time` (N,).

    The base must lie inside [time[0], time[-1]] (crop it with common_span first): extrapolating
    a force or a joint angle would invent data.
    """
    base_time = np.asarray(base_time, dtype=np.float64)
    time = np.asarray(time, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if time.ndim != 1 or values.shape[0] != time.shape[0]:
        raise ValueError(f'time {time.shape} and values {values.shape} lengths differ')
    if time.size < 2 or np.any(np.diff(time) <= 0.0):
        raise ValueError('source time stamps must be at least 2 and strictly increasing')
    if base_time.size and (base_time[0] < time[0] or base_time[-1] > time[-1]):
        raise ValueError(f'base time [{base_time[0]:.3f}, {base_time[-1]:.3f}] s leaves the '
                         f'source span [{time[0]:.3f}, {time[-1]:.3f}] s; crop with common_span')
    flat = values.reshape(values.shape[0], -1)
    out = np.column_stack([np.interp(base_time, time, column) for column in flat.T])
    return out.reshape((base_time.shape[0],) + values.shape[1:])


# --- (3) projection ------------------------------------------------------------------------------

def project_force(force: np.ndarray, rotations: np.ndarray, atol: float = 1e-6) -> np.ndarray:
    """f^0 = R^0_F(t) f^F: force (N, 3) in {F} -> {S0} with rotations (N, 3, 3)."""
    force = np.asarray(force, dtype=np.float64)
    rotations = np.asarray(rotations, dtype=np.float64)
    if force.ndim != 2 or force.shape[1] != 3 or rotations.shape != (force.shape[0], 3, 3):
        raise ValueError(f'need force (N, 3) and rotations (N, 3, 3), got {force.shape} and '
                         f'{rotations.shape}')
    gram_error = np.abs(np.einsum('nji,njk->nik', rotations, rotations) - np.eye(3)).max(
        initial=0.0)
    if not gram_error <= atol or not np.all(np.linalg.det(rotations) > 0.0):
        raise ValueError(f'rotations are not proper rotation matrices (max |R^T R - I| = '
                         f'{gram_error:.2e})')
    return np.einsum('nij,nj->ni', rotations, force)


# --- (4) offsets ---------------------------------------------------------------------------------

def static_mask(force: np.ndarray, taxels: np.ndarray, fs: float = SAMPLE_RATE_HZ,
                force_threshold: float = 0.3, activity_threshold: float = 15.0,
                min_duration: float = 0.5, margin: float = 0.2,
                rest_share: float = 0.1) -> np.ndarray:
    """Samples inside static no-contact segments: (N,) bool. taxels: (N, n, 3) counts.

    The no-contact reference comes from the recording itself, so an un-zeroed F/T bias of any
    size does not hide the rests. Released, the F/T sensor reads its bias, of one magnitude
    through every rest, and the taxels read their rest counts, while presses sweep through both:
    the `rest_share` of samples nearest the reading that recurs most are released ones (the
    operator rests between presses; the paper's sessions rest about a quarter of the time).
    Their median is the rest reading of the taxels and of the F/T sensor. Static = force within
    `force_threshold` [N] of the F/T's rest reading AND tactile activity below
    `activity_threshold` [counts, rms over channels of the deviation from the taxels' rest],
    held for at least `min_duration` [s] after dropping `margin` [s] at both ends of each run
    (the onset and release of a press are below the thresholds but not at rest).
    """
    force = np.asarray(force, dtype=np.float64)
    taxels = np.asarray(taxels, dtype=np.float64)
    rest, force_rest = rest_reading(force, taxels, rest_share, activity_threshold)
    flat = taxels.reshape(force.shape[0], -1)
    activity = np.sqrt(np.mean((flat - rest) ** 2, axis=1))
    candidate = ((np.linalg.norm(force - force_rest, axis=1) < force_threshold)
                 & (activity < activity_threshold))
    min_len = max(1, int(round(min_duration * fs)))
    trim = int(round(margin * fs))
    mask = np.zeros_like(candidate)
    for start, stop in true_runs(candidate):
        if stop - start - 2 * trim >= min_len:
            mask[start + trim:stop - trim] = True
    return mask


def rest_reading(force: np.ndarray, taxels: np.ndarray, rest_share: float = 0.1,
                 activity_threshold: float = 15.0) -> tuple[np.ndarray, np.ndarray]:
    """(flat taxel counts, force) of a recording at rest: the medians over its released samples
    (static_mask says how they are found; `activity_threshold` [counts rms] as there)."""
    force = np.asarray(force, dtype=np.float64)
    taxels = np.asarray(taxels, dtype=np.float64)
    if taxels.ndim != 3 or taxels.shape[2] != 3 or taxels.shape[0] != force.shape[0]:
        raise ValueError(f'need taxels (N, n, 3) matching force (N, 3), got {taxels.shape} and '
                         f'{force.shape}')
    if not 0.0 < rest_share < 0.5:
        raise ValueError(f'rest_share {rest_share} must lie in (0, 0.5)')
    if not activity_threshold > 0.0:
        raise ValueError(f'activity_threshold {activity_threshold} must be positive')
    flat = taxels.reshape(force.shape[0], -1)
    released = _released(force, flat, rest_share, REST_SPREAD * activity_threshold)
    return np.median(flat[released], axis=0), np.median(force[released], axis=0)


REST_RADIUS = 0.03       # N: about the F/T sensor's noise, well below a press
DENSITY_PROBES = 256     # candidate samples, spread over the recording
# Rests of one session read their taxels a little apart (the skin's creep and hysteresis: on
# the magnetic skin 20-30 counts rms between the first rest and one after presses of 1.5-3.5 N,
# index_proximal on the button plate), presses hundreds of counts from them: the rests are one
# cluster within this many activity thresholds.
REST_SPREAD = 3.0


def _released(force: np.ndarray, flat: np.ndarray, share: float,
              taxel_radius: float) -> np.ndarray:
    """(N,) bool: the `share` of samples nearest the reading that recurs most, a force
    magnitude within REST_RADIUS [N] together with taxel counts within `taxel_radius` [counts
    rms] of it. Released, the F/T sensor reads its bias, the same magnitude through every rest
    whatever frame the force is expressed in as the hand moves between presses, and the taxels
    their rest counts; presses sweep through both. Either alone can mislead: a press can keep
    the force's magnitude at the bias's (a press against a bias of the same size), and the
    taxels' rest counts recur in any span where the F/T sensor reads a load the skin does not
    feel (a press on another array, an F/T lag)."""
    magnitude = np.sqrt(np.sum(force * force, axis=1))

    def distance(magnitude_0: float, flat_0: np.ndarray,
                 rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Per sample, the larger of its force and taxel distances to a reading, each over its
        radius (so <= 1 is near in both)."""
        taxel_rms = np.sqrt(np.mean((flat[rows] - flat_0) ** 2, axis=1))
        return np.maximum(np.abs(magnitude[rows] - magnitude_0) / REST_RADIUS,
                          taxel_rms / taxel_radius)

    probes = np.linspace(0, len(magnitude) - 1,
                         min(len(magnitude), DENSITY_PROBES)).astype(np.int64)
    density = np.zeros(len(probes), np.int64)
    for k, probe in enumerate(probes):
        near_force = np.flatnonzero(np.abs(magnitude - magnitude[probe]) <= REST_RADIUS)
        density[k] = np.count_nonzero(
            distance(magnitude[probe], flat[probe], near_force) <= 1.0)
    # The densest probe's neighbours, measured from their median: a probe is one noisy sample.
    densest = probes[int(np.argmax(density))]
    cluster = distance(magnitude[densest], flat[densest]) <= 1.0
    nearest = distance(float(np.median(magnitude[cluster])), np.median(flat[cluster], axis=0))
    return nearest <= np.quantile(nearest, share)


def true_runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the True runs of a 1-D bool array."""
    edges = np.diff(np.concatenate(([0], flags.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


@dataclass(frozen=True)
class Offsets:
    taxels: np.ndarray      # (n, 3) counts
    force: np.ndarray       # (3,) N
    n_static: int           # samples they were averaged over


def static_offsets(force: np.ndarray, taxels: np.ndarray, **static_kw) -> Offsets:
    """Mean taxel and force reading over the static segments of one recording session."""
    mask = static_mask(force, taxels, **static_kw)
    if not mask.any():
        raise StaticSegmentError(
            'no static no-contact segment found (force and tactile activity both low for long '
            'enough); record a rest period or relax force_threshold/activity_threshold/'
            'min_duration')
    taxels = np.asarray(taxels, dtype=np.float64)
    return Offsets(taxels=taxels[mask].mean(axis=0),
                   force=np.asarray(force, dtype=np.float64)[mask].mean(axis=0),
                   n_static=int(mask.sum()))


def remove_offsets(force: np.ndarray, taxels: np.ndarray, sessions: np.ndarray,
                   **static_kw) -> tuple[np.ndarray, np.ndarray, dict[int, Offsets]]:
    """Subtract each session's own static offsets (baselines drift between sessions)."""
    force = np.array(force, dtype=np.float64)
    taxels = np.array(taxels, dtype=np.float64)
    offsets = {}
    for session in np.unique(sessions):
        rows = sessions == session
        try:
            off = static_offsets(force[rows], taxels[rows], **static_kw)
        except StaticSegmentError as exc:
            raise StaticSegmentError(f'session {session}: {exc}') from None
        force[rows] -= off.force
        taxels[rows] -= off.taxels
        offsets[int(session)] = off
    return force, taxels, offsets


# --- (5) standardisation -------------------------------------------------------------------------

@dataclass(frozen=True)
class Standardiser:
    """Per-channel (x - mean) / std; channels with std <= floor are flagged dead and use std = 1.

    A dead channel (constant in training) then maps to 0 during training instead of inf/NaN,
    and a reading that comes alive later shows up as a large standardised value (OOD score).
    """

    mean: np.ndarray
    std: np.ndarray
    dead: np.ndarray

    @classmethod
    def fit(cls, data: np.ndarray, floor: float) -> Standardiser:
        data = np.asarray(data, dtype=np.float64)
        if data.shape[0] < 1 or not np.all(np.isfinite(data)):
            raise ValueError('standardisation needs at least one sample and finite data')
        mean = data.mean(axis=0)
        std = data.std(axis=0)
        dead = ~(std > floor)
        return cls(mean=mean, std=np.where(dead, 1.0, std), dead=dead)

    def transform(self, data: np.ndarray) -> np.ndarray:
        return (np.asarray(data, dtype=np.float64) - self.mean) / self.std

    def inverse(self, data: np.ndarray) -> np.ndarray:
        return np.asarray(data, dtype=np.float64) * self.std + self.mean


# Floors: a taxel channel varying by less than one ADC count carries no information; a force
# axis varying by less than 1 mN is below any F/T sensor's resolution.
TAXEL_STD_FLOOR = 1.0
FORCE_STD_FLOOR = 1e-3
