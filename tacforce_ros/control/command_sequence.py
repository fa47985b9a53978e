"""Force command sequences: piecewise-constant or linear 3-D force set-points over time.

File format (YAML, config/commands/<name>.yaml):

    frame_id: ft_sensor          # frame the forces are expressed in
    segments:                    # played in order, starting at t = 0
      - {duration: 15.0, force: [0.0, 0.0, 0.0]}                 # hold (shape: step, default)
      - {duration: 1.0, force: [0.0, 0.0, 1.0], shape: ramp}     # linear from the previous end

A `step` segment holds `force` for `duration`; a `ramp` segment goes linearly from where the
previous segment ended (zero for the first) to `force`. Newtons and seconds.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from tacforce_ros.paths import config_dir

SHAPES = ('step', 'ramp')


class SequenceError(ValueError):
    """A command sequence file that cannot be played; the message names the file and field."""


@dataclass(frozen=True)
class ForceSequence:
    frame_id: str
    starts: np.ndarray      # (k,) s, segment start times
    durations: np.ndarray   # (k,) s
    begin: np.ndarray       # (k, 3) N, force at each segment's start
    end: np.ndarray         # (k, 3) N, force at each segment's end
    source: str = ''

    @property
    def duration(self) -> float:
        return float(self.starts[-1] + self.durations[-1])

    def force_at(self, t: float) -> np.ndarray:
        """Force at time t (s) from the start; before 0 the first value, after the end the last."""
        if t >= self.duration:
            return self.end[-1].copy()
        k = max(int(self.starts.searchsorted(t, side='right')) - 1, 0)
        alpha = min(max((t - self.starts[k]) / self.durations[k], 0.0), 1.0)
        return self.begin[k] + alpha * (self.end[k] - self.begin[k])

    def until(self, seconds: float) -> ForceSequence:
        """The same commands cut off at `seconds` (the whole sequence if it is shorter)."""
        if not seconds > 0.0:
            raise SequenceError(f'cannot cut a sequence at {seconds} s')
        keep = self.starts < seconds
        durations = np.minimum(self.durations[keep], seconds - self.starts[keep])
        begin, end = self.begin[keep], self.end[keep].copy()
        end[-1] = begin[-1] + durations[-1] / self.durations[keep][-1] * (end[-1] - begin[-1])
        return ForceSequence(self.frame_id, self.starts[keep], durations, begin, end,
                             f'{self.source} until {seconds:g} s')

    @classmethod
    def from_mapping(cls, doc: object, source: str = '<mapping>') -> ForceSequence:
        if not isinstance(doc, dict):
            raise SequenceError(f'{source}: expected a mapping with frame_id and segments')
        frame_id = doc.get('frame_id')
        if not isinstance(frame_id, str) or not frame_id:
            raise SequenceError(f'{source}: frame_id must be a non-empty string')
        segments = doc.get('segments')
        if not isinstance(segments, list) or not segments:
            raise SequenceError(f'{source}: segments must be a non-empty list')
        durations, begin, end = [], [], []
        previous = np.zeros(3)
        for i, seg in enumerate(segments):
            where = f'{source}: segments[{i}]'
            if not isinstance(seg, dict) or set(seg) - {'duration', 'force', 'shape'}:
                raise SequenceError(f'{where}: expected keys duration, force and optional shape')
            duration = seg.get('duration')
            if not isinstance(duration, (int, float)) or not np.isfinite(duration) \
                    or duration <= 0:
                raise SequenceError(f'{where}.duration: {duration!r} must be a positive number')
            try:
                force = np.asarray(seg.get('force'), dtype=np.float64)
            except (TypeError, ValueError):
                force = np.full(1, np.nan)
            if force.shape != (3,) or not np.all(np.isfinite(force)):
                raise SequenceError(f'{where}.force: {seg.get("force")!r} must be 3 numbers (N)')
            shape = seg.get('shape', 'step')
            if shape not in SHAPES:
                raise SequenceError(f'{where}.shape: {shape!r} is not one of {SHAPES}')
            durations.append(float(duration))
            begin.append(previous if shape == 'ramp' else force)
            end.append(force)
            previous = force
        durations_arr = np.asarray(durations)
        starts = np.concatenate([[0.0], np.cumsum(durations_arr)[:-1]])
        return cls(frame_id=frame_id, starts=starts, durations=durations_arr,
                   begin=np.asarray(begin), end=np.asarray(end), source=source)

    @classmethod
    def load(cls, name_or_path: str | Path) -> ForceSequence:
        """A file path, or a name under config/commands/ (with or without .yaml)."""
        path = Path(name_or_path).expanduser()
        if not path.is_file():
            candidate = config_dir() / 'commands' / path.name
            path = candidate if candidate.suffix else candidate.with_suffix('.yaml')
        if not path.is_file():
            raise SequenceError(f'{name_or_path}: no such file, nor a sequence named so in '
                                f'{config_dir() / "commands"}')
        try:
            doc = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise SequenceError(f'{path}: not valid YAML: {exc}') from None
        return cls.from_mapping(doc, str(path))
