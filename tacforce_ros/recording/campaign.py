"""A calibration campaign: which array is pressed on which plate, how often, what is still missing.

The paper calibrated the index fingertip and intermediate phalanx arrays on six 3-D printed
push-plates, 4 x 100 s per plate ("data collection is repeated for each fingertip and
intermediate phalanx array"). A campaign extends that to every array of the hand: the plate
stands on the F/T sensor and the operator brings the hand to it, so every plate reaches every
array on the rig (the palm pads too, with the fingers open); the plates are what differs in
shape, not in reach. The order is plate by plate (a plate change means unscrewing it from the
sensor; moving the hand to the next array does not), array by array within a plate.

A campaign is a folder: `campaign.yaml` (the plan) and the session bags, found by their session
metadata (array, plate), so bags from the lab recorder and from `sim_record` count alike. A
session counts when its bag reads and its coverage verdict passes; a bag whose coverage is poor
is moved to `rejected/` (kept, not counted) and its session is due again. Pure Python over numpy.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from tacforce_ros.estimation.dataset import CalibrationDataset
from tacforce_ros.estimation.preprocessing import rest_reading, static_mask, true_runs

PLAN_FILE = 'campaign.yaml'
VERDICTS_FILE = 'verdicts.json'
REJECTED = 'rejected'
# Operator time per session besides the pressing, and per plate change: our estimates.
SESSION_OVERHEAD_S = 20.0
PLATE_CHANGE_S = 120.0
REFERENCE_SESSION_S = 100.0     # the paper's session, which CoverageLimits' defaults are for


class CampaignError(ValueError):
    """A campaign folder or plan that cannot be used; the message says why."""


@dataclass(frozen=True)
class CoverageLimits:
    """What a session must contain to be worth training on (estimates, from what the training
    needs: force up to the range the models must cover, shear in most directions, and rests
    for the per-session offsets)."""
    min_peak_force: float = 2.0         # N, largest |F| pressed
    shear_force: float = 0.1            # N, tangential force that counts for a direction
    shear_sectors: int = 8              # directions around the normal ...
    min_shear_sectors: int = 6          # ... of which this many must be pressed
    min_rests: int = 3                  # static no-contact segments (offset estimation)

    def for_session(self, seconds: float) -> CoverageLimits:
        """The limits for a session of `seconds`: these are for the paper's 100 s session; a
        shorter one (a campaign with a budget) is asked for shear directions and rests in
        proportion to its length, at least one of each (a rest gives the session its
        offsets), and the same peak force."""
        if seconds >= REFERENCE_SESSION_S:
            return self
        share = seconds / REFERENCE_SESSION_S
        return replace(self, min_shear_sectors=max(1, math.ceil(self.min_shear_sectors * share)),
                       min_rests=max(1, math.ceil(self.min_rests * share)))


@dataclass(frozen=True)
class Coverage:
    peak_force: float
    shear_sectors: int
    rests: int
    samples: int
    problems: tuple[str, ...]
    sectors: tuple[int, ...] = ()      # which directions were pressed (0 .. shear_sectors-1)

    @property
    def ok(self) -> bool:
        return not self.problems


def session_coverage(dataset: CalibrationDataset, limits: CoverageLimits = CoverageLimits()
                     ) -> Coverage:
    """Force range, shear directions and rests of one session."""
    return coverage_of(dataset.F, dataset.X, limits)


def coverage_of(force: np.ndarray, tactile: np.ndarray,
                limits: CoverageLimits = CoverageLimits()) -> Coverage:
    """Coverage of force samples (N, 3) in the array frame and their tactile frames (N, taxels,
    3), from the session's own rest reading (the F/T is not zeroed). Sector k holds the shear
    directions at angles [-180 + k * 360 / sectors, ...) deg from the array's +x."""
    force = np.asarray(force, np.float64)
    tactile = np.asarray(tactile, np.float64)
    rests = len(true_runs(static_mask(force, tactile)))
    pressed = force - rest_reading(force, tactile)[1]
    peak = float(np.linalg.norm(pressed, axis=1).max(initial=0.0))
    tangential = pressed[:, :2]
    shearing = np.linalg.norm(tangential, axis=1) >= limits.shear_force
    angles = np.arctan2(tangential[shearing, 1], tangential[shearing, 0])
    seen = np.unique(np.floor((angles + np.pi) / (2 * np.pi) * limits.shear_sectors)
                     .astype(int) % limits.shear_sectors)
    problems = []
    if peak < limits.min_peak_force:
        problems.append(f'press harder: peak force {peak:.2f} N < {limits.min_peak_force} N')
    if seen.size < limits.min_shear_sectors:
        problems.append(f'vary the push direction: shear in {seen.size} of '
                        f'{limits.shear_sectors} directions < {limits.min_shear_sectors}')
    if rests < limits.min_rests:
        problems.append(f'let go between presses: {rests} rests < {limits.min_rests}')
    return Coverage(peak, int(seen.size), rests, int(force.shape[0]), tuple(problems),
                    tuple(int(k) for k in seen))


class LiveCoverage:
    """The coverage of a session while it is recorded, from its synchronised samples (the
    recorder's /calibration/sample), judged as `coverage_of` judges the closed bag. The bag's
    verdict low-passes and resamples first, so near a limit the two can differ slightly."""

    def __init__(self, kinematics, ft_frame: str, array_frame: str,
                 limits: CoverageLimits = CoverageLimits()) -> None:
        self.kinematics, self.ft_frame, self.array_frame = kinematics, ft_frame, array_frame
        self.limits = limits
        self._force: list[np.ndarray] = []
        self._tactile: list[np.ndarray] = []

    def add(self, tactile: np.ndarray, force_ft: np.ndarray, q16: np.ndarray) -> None:
        """One sample: raw taxel readings (taxels, 3), the F/T force in its frame, joints."""
        rotation = self.kinematics.rotation_between(q16, self.ft_frame, self.array_frame)
        self._force.append(rotation @ np.asarray(force_ft, np.float64))
        self._tactile.append(np.asarray(tactile, np.float64))

    @property
    def samples(self) -> int:
        return len(self._force)

    def coverage(self) -> Coverage | None:
        """None until there are two samples."""
        if self.samples < 2:
            return None
        return coverage_of(np.stack(self._force), np.stack(self._tactile), self.limits)


def coverage_view(title: str, coverage: Coverage | None, limits: CoverageLimits,
                  elapsed: float, planned: float = 0.0, width: int = 30) -> str:
    """A few lines for the operator's terminal: time, force, directions, rests, what is left."""
    if planned > 0:
        done = min(elapsed / planned, 1.0)
        bar = '#' * int(round(done * width))
        clock = f'[{bar:<{width}}] {elapsed:5.0f} / {planned:.0f} s'
    else:
        clock = f'{elapsed:.0f} s'
    lines = [f'{title}  {clock}']
    if coverage is None:
        return '\n'.join(lines + ['  waiting for synchronised samples (/calibration/sample)'])
    step = 360.0 / limits.shear_sectors
    compass = ' '.join(f'{-180 + (k + 0.5) * step:+.0f}:{"#" if k in coverage.sectors else "."}'
                       for k in range(limits.shear_sectors))
    lines += [
        f'  peak force {coverage.peak_force:5.2f} N   (need {limits.min_peak_force:g})',
        f'  shear      {coverage.shear_sectors} of {limits.shear_sectors} directions (need '
        f'{limits.min_shear_sectors}): {compass} deg from +x',
        f'  rests      {coverage.rests}   (need {limits.min_rests})',
        '  so far: ' + ('enough' if coverage.ok else '; '.join(coverage.problems))]
    return '\n'.join(lines)


def verdict_line(name: str, coverage: Coverage | None, reason: str = '') -> str:
    """One line on a judged bag (Campaign.check's progress), as the tools print it."""
    if coverage is None:
        return f'{name}: {reason}'
    verdict = 'ok' if coverage.ok else 'REDO: ' + '; '.join(coverage.problems)
    return (f'{name}: peak {coverage.peak_force:.2f} N, shear in {coverage.shear_sectors} '
            f'directions, {coverage.rests} rests -> {verdict}')


@dataclass(frozen=True)
class SessionSlot:
    array: str
    plate: str
    index: int          # 0 .. sessions-1 of its (array, plate)

    @property
    def name(self) -> str:
        return f'{self.array}_{self.plate}_s{self.index}'


@dataclass(frozen=True)
class CampaignPlan:
    hand_side: str
    arrays: tuple[str, ...]
    plates: tuple[str, ...]
    sessions: int               # per (array, plate)
    seconds: float              # per session, unless `durations` says otherwise
    seed: int = 0               # simulated campaigns: base seed of the sessions
    limits: CoverageLimits = field(default_factory=CoverageLimits)
    # A budget plan (`campaign plan --budget`): seconds per session of each array, and the
    # expected-error curves and budget it was chosen with (recording/budget.py).
    durations: dict[str, float] = field(default_factory=dict)
    budget: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.arrays or not self.plates:
            raise CampaignError('a campaign needs at least one array and one plate')
        if self.sessions < 1 or not self.seconds > 0:
            raise CampaignError(f'sessions ({self.sessions}) must be >= 1 and seconds '
                                f'({self.seconds}) > 0')
        unknown = sorted(set(self.durations) - set(self.arrays))
        if unknown or not all(float(s) > 0 for s in self.durations.values()):
            raise CampaignError(f'durations: seconds > 0 of arrays of the plan, got '
                                f'{self.durations}')

    def session_seconds(self, array: str) -> float:
        """How long each session of `array` lasts."""
        return float(self.durations.get(array, self.seconds))

    def limits_for(self, array: str) -> CoverageLimits:
        """The coverage a session of `array` must have: the plan's limits, for the length of
        its sessions where the plan sets one (CoverageLimits.for_session)."""
        if array in self.durations:
            return self.limits.for_session(self.durations[array])
        return self.limits

    def pressing_s(self, slots: list[SessionSlot] | None = None) -> float:
        """Seconds of pressing in `slots` (default: all)."""
        slots = self.slots() if slots is None else slots
        return sum(self.session_seconds(s.array) for s in slots)

    def slots(self) -> list[SessionSlot]:
        """Every session, in the order the operator records them (plate by plate)."""
        return [SessionSlot(a, p, k) for p in self.plates for a in self.arrays
                for k in range(self.sessions)]

    def duration_s(self, slots: list[SessionSlot] | None = None) -> float:
        """Operator time for `slots` (default: all), with the overheads we estimate."""
        slots = self.slots() if slots is None else slots
        plates = len({s.plate for s in slots})
        return self.pressing_s(slots) + len(slots) * SESSION_OVERHEAD_S + plates * PLATE_CHANGE_S

    def save(self, folder: Path) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        raw = asdict(self)
        raw['arrays'], raw['plates'] = list(self.arrays), list(self.plates)
        raw['durations'] = {a: float(s) for a, s in self.durations.items()}
        if not self.durations:
            del raw['durations']
        if not self.budget:
            del raw['budget']
        path = folder / PLAN_FILE
        path.write_text('# Calibration campaign (tacforce_ros.recording.campaign)\n'
                        + yaml.safe_dump(raw, sort_keys=False))
        return path

    @classmethod
    def load(cls, folder: Path) -> CampaignPlan:
        path = Path(folder).expanduser() / PLAN_FILE
        if not path.is_file():
            raise CampaignError(f'{folder}: not a campaign (no {PLAN_FILE}; make one with '
                                '`campaign plan`)')
        try:
            raw = yaml.safe_load(path.read_text())
            if not isinstance(raw, dict):
                raise TypeError('the top level is not a mapping')
            limits = CoverageLimits(**(raw.pop('limits', None) or {}))
            durations = {str(a): float(s) for a, s in (raw.pop('durations', None) or {}).items()}
            return cls(**{**raw, 'arrays': tuple(raw['arrays']), 'plates': tuple(raw['plates']),
                          'limits': limits, 'durations': durations,
                          'budget': dict(raw.get('budget') or {})})
        except (yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as exc:
            raise CampaignError(f'{path}: not a campaign plan ({exc})') from None


@dataclass
class SessionRecord:
    bag: str            # folder name, relative to the campaign
    array: str
    plate: str
    coverage: dict

    @property
    def ok(self) -> bool:
        return not self.coverage['problems']


class Campaign:
    """A campaign folder: its plan, the bags it holds, and what is still due."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder).expanduser()
        self.plan = CampaignPlan.load(self.folder)
        self._verdicts: dict[str, dict] = {}
        verdicts = self.folder / VERDICTS_FILE
        if verdicts.is_file():
            try:
                self._verdicts = json.loads(verdicts.read_text())
            except ValueError:
                pass        # judged again: the bags are what counts, not the file

    @classmethod
    def create(cls, folder: str | Path, plan: CampaignPlan) -> Campaign:
        folder = Path(folder)
        if (folder / PLAN_FILE).is_file():
            existing = CampaignPlan.load(folder)
            if existing != plan:
                raise CampaignError(f'{folder} holds another campaign plan; resume it with '
                                    '`campaign run`/`status`, or choose another folder')
        else:
            plan.save(folder)
        return cls(folder)

    def bags(self) -> list[Path]:
        """Bag folders directly inside the campaign folder (a lab bag still being recorded is
        among them: it fails to read until closed, and is judged then)."""
        return sorted(p for p in self.folder.iterdir()
                      if p.is_dir() and (p / 'metadata.yaml').is_file())

    def check(self, hand, kinematics, progress=None, write: bool = True,
              read: dict | None = None) -> list[SessionRecord]:
        """Judge every bag not yet judged (a verdict holds for the bag as it was, under the
        plan's limits); with `write`, move a poor one to rejected/ and keep the verdicts.
        Returns the records of the bags that count. A bag that does not read is reported
        through `progress(name, None, reason)` and left alone. `read`, if given, receives
        bag path -> (dataset, messages dropped) of each counted bag this call read, so that a
        caller that needs the datasets reads no bag twice."""
        from tacforce_ros.bagio import BagError
        from tacforce_ros.estimation.bag_dataset import dataset_from_bag
        from tacforce_ros.estimation.dataset import DatasetError

        records, verdicts = [], {}
        try:
            for bag in self.bags():
                stamp = (bag / 'metadata.yaml').stat().st_mtime_ns
                verdict = self._verdicts.get(bag.name)
                fresh = None
                if verdict is None or verdict.get('stamp') != stamp or verdict.get(
                        'limits') != asdict(self.plan.limits_for(verdict.get('array'))):
                    try:
                        dataset, dropped = dataset_from_bag(bag, hand, kinematics)
                    except (BagError, DatasetError, ValueError, KeyError, OSError) as exc:
                        if progress is not None:
                            progress(bag.name, None, f'not counted, does not read: {exc}')
                        continue
                    if dataset.hand_side != self.plan.hand_side:
                        if progress is not None:
                            progress(bag.name, None, f'not counted: a bag of the '
                                     f'{dataset.hand_side} hand')
                        continue
                    limits = self.plan.limits_for(dataset.array)
                    coverage = session_coverage(dataset, limits)
                    fresh = (dataset, dropped)
                    verdict = {'array': dataset.array, 'plate': dataset.plate_names()[0],
                               'coverage': asdict(coverage), 'stamp': stamp,
                               'limits': asdict(limits)}
                    if progress is not None:
                        progress(bag.name, coverage, '')
                record = SessionRecord(bag.name, verdict['array'], verdict['plate'],
                                       verdict['coverage'])
                if record.ok:
                    verdicts[bag.name] = verdict
                    records.append(record)
                    if read is not None and fresh is not None:
                        read[bag] = fresh
                elif write:
                    self._reject(bag, verdict)
        finally:
            self._verdicts = verdicts
            if write:
                self._save_verdicts()
        return records

    def _reject(self, bag: Path, verdict: dict) -> None:
        rejected = self.folder / REJECTED
        rejected.mkdir(exist_ok=True)
        target = rejected / bag.name
        if target.exists():
            target = rejected / f'{bag.name}_{len(list(rejected.iterdir()))}'
        bag.rename(target)
        (target.parent / f'{target.name}.verdict.json').write_text(json.dumps(verdict, indent=2))

    def _save_verdicts(self) -> None:
        path = self.folder / VERDICTS_FILE
        partial = path.with_name(path.name + '.partial')
        partial.write_text(json.dumps(self._verdicts, indent=2, sort_keys=True))
        partial.replace(path)

    def rejected_count(self, array: str, plate: str) -> int:
        """How many bags of (array, plate) were judged poor and set aside."""
        folder = self.folder / REJECTED
        if not folder.is_dir():
            return 0
        verdicts = [json.loads(p.read_text()) for p in folder.glob('*.verdict.json')]
        return sum((v.get('array'), v.get('plate')) == (array, plate) for v in verdicts)

    def due(self, records: list[SessionRecord]) -> list[SessionSlot]:
        """The planned sessions no counted bag covers yet, in recording order; each takes the
        lowest session index whose bag name is free (rejected bags keep theirs)."""
        done: dict[tuple[str, str], int] = {}
        for record in records:
            key = (record.array, record.plate)
            done[key] = done.get(key, 0) + 1
        taken = {p.name for p in self.folder.iterdir()}
        if (self.folder / REJECTED).is_dir():
            taken |= {p.name for p in (self.folder / REJECTED).iterdir()}
        due = []
        for plate in self.plan.plates:
            for array in self.plan.arrays:
                missing = self.plan.sessions - done.get((array, plate), 0)
                index = 0
                while missing > 0:
                    slot = SessionSlot(array, plate, index)
                    index += 1
                    if slot.name not in taken:
                        due.append(slot)
                        missing -= 1
        return due

    def counted_bags(self, records: list[SessionRecord]) -> list[Path]:
        """The bags to train on: counted, and at most `sessions` per (array, plate)."""
        kept: dict[tuple[str, str], list[str]] = {}
        for record in records:
            kept.setdefault((record.array, record.plate), []).append(record.bag)
        return [self.folder / bag for key in sorted(kept)
                for bag in sorted(kept[key], key=_natural)[:self.plan.sessions]
                if key[0] in self.plan.arrays and key[1] in self.plan.plates]


def _natural(name: str) -> list:
    """Sort key: digits as numbers (s2 before s10)."""
    return [int(part) if part.isdigit() else part for part in re.split(r'(\d+)', name)]


def is_campaign(path: Path) -> bool:
    return (Path(path) / PLAN_FILE).is_file()
