"""A campaign with a budget: how long each array is pressed, so that the whole hand's expected
held-out error is least for the pressing time a lab has.

The expected error of an array is read off a kind curve (estimation/learning_curve.kind_curve):
the held-out e_hat of the model a kind's arrays share, adapted to one of them, when every array
of the kind has the same seconds; the curve of a kind is the mean over its arrays. The arrays of
a kind are alike before they are pressed, so each kind gets one session length; every array is
pressed on every plate of the plan, one session per plate, because the held-out error that
judges a model is leave-one-plate-out and the shared model needs each plate in the pool. The
allocation is exact over a grid of session lengths: a knapsack over the kinds, kept as the
Pareto front of pressing time against summed expected error.
Pure Python over numpy.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

# Shortest session a budget plan asks for: an estimate, from the simulated operator (press 2-6 s,
# release 0.6-2 s; config/scenes/_calibration.yaml). The first 60 simulated sessions of a main
# job, cut short, met the limits for their length (CoverageLimits.for_session): 54 at 10 s,
# 57 at 15 s, 60 at 20 s and 30 s. A session judged poor is pressed again, which the budget
# pays for.
MIN_SESSION_S = 20.0
STEP_S = 5.0                # the grid of session lengths the allocation chooses from
# Share of the budget held back for sessions pressed again after a poor verdict: an estimate
# (the quick main job pressed 1 of its 15 20-s sessions again).
RESERVE = 0.05
WAY = 'shared-kind'         # the learning-curve rows a budget plans on
WAYS = (WAY, WAY + '+pool')     # learning_curve --kind-curve, without and with --pool


class BudgetError(ValueError):
    """A budget, a curve or an allocation that cannot be used; the message says why."""


def parse_budget(text: str) -> float:
    """'60m', '1h', '1.5h', '3600s' or '3600' (seconds) -> seconds of pressing."""
    match = re.fullmatch(r'\s*(\d+(?:\.\d*)?)\s*([hms]?)\s*', str(text))
    if not match:
        raise BudgetError(f'budget {text!r}: a duration such as 60m, 1.5h or 3600s')
    value = float(match.group(1)) * {'h': 3600.0, 'm': 60.0, 's': 1.0, '': 1.0}[match.group(2)]
    if not value > 0:
        raise BudgetError(f'budget {text!r}: must be > 0')
    return value


@dataclass(frozen=True)
class ExpectedError:
    """Expected held-out e_hat [N] of an array's adapted model per kind, against the seconds
    the array is pressed: points (seconds, e_hat) per kind, log-log interpolated between them
    and held at the ends (the curve says nothing outside its points: `expected` says which side
    of them a value lies on). `pooled`: the curves' shared models had the other hand's pool,
    so a kind with fewer than three arrays on this hand still has a shared model."""

    curves: Mapping[str, tuple[tuple[float, float], ...]]
    source: str = ''
    pooled: bool = False

    def __post_init__(self) -> None:
        for kind, points in self.curves.items():
            seconds = [s for s, _ in points]
            if not points or seconds != sorted(set(seconds)) or \
                    not all(s > 0 and e > 0 and math.isfinite(e) for s, e in points):
                raise BudgetError(f'expected error of {kind}: points (seconds, e_hat) with '
                                  f'increasing seconds > 0 and e_hat > 0, got {points}')

    @classmethod
    def from_rows(cls, rows: Sequence[Mapping[str, Any]], source: str = '') -> ExpectedError:
        """From kind-curve rows (learning_curve.json `rows`, or report.json `learning_curve`'s,
        way 'shared-kind', or 'shared-kind+pool' with the other hand's pool): per kind and
        point, the mean e_hat over its arrays. Rows of both ways are refused: a plan is made on
        the one the campaign will be trained with."""
        points: dict[str, dict[float, list[float]]] = {}
        ways = {row.get('way') for row in rows} & set(WAYS)
        if len(ways) > 1:
            raise BudgetError(f'{source or "the rows"}: kind curves with and without the other '
                              f'hand\'s pool ({sorted(ways)}); plan on the one `train` will use')
        for row in rows:
            if row.get('way') in WAYS and row.get('e_hat_n') is not None:
                points.setdefault(row['kind'], {}).setdefault(float(row['seconds']), []).append(
                    float(row['e_hat_n']))
        if not points:
            raise BudgetError(f'{source or "the rows"}: no kind-curve rows (way {WAY!r}; '
                              '`learning_curve ... --kind-curve` makes them)')
        return cls({kind: tuple((s, float(np.mean(e))) for s, e in sorted(by_s.items()))
                    for kind, by_s in points.items()}, source, ways == {WAYS[1]})

    def to_dict(self) -> dict[str, Any]:
        return {'source': self.source, 'pooled': self.pooled,
                'curves': {k: [list(p) for p in v] for k, v in self.curves.items()}}

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any]) -> ExpectedError:
        try:
            return cls({str(k): tuple((float(s), float(e)) for s, e in v)
                        for k, v in raw['curves'].items()}, str(raw.get('source', '')),
                       bool(raw.get('pooled', False)))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise BudgetError(f'expected error: not a curve set ({exc})') from None

    def expected(self, kind: str, seconds: float) -> tuple[float, int]:
        """(e_hat [N], side) for an array of `kind` pressed `seconds`: side 0 within the curve's
        points, -1 below its first (the value a lower bound), +1 beyond its last (an upper
        bound)."""
        if kind not in self.curves:
            raise BudgetError(f'no expected-error curve for {kind} arrays (curves: '
                              f'{sorted(self.curves)})')
        s, e = np.array(self.curves[kind]).T
        side = -1 if seconds < s[0] else 1 if seconds > s[-1] else 0
        if seconds <= s[0] or len(s) == 1:
            return float(e[0]), side
        if seconds >= s[-1]:
            return float(e[-1]), side
        return float(np.exp(np.interp(np.log(seconds), np.log(s), np.log(e)))), side


@dataclass(frozen=True)
class Allocation:
    """Seconds per session of each kind, one session per plate, and what that is expected to
    give."""

    session_s: Mapping[str, float]          # kind -> seconds of each session
    plates: int
    arrays: Mapping[str, int]               # kind -> arrays of the kind in the plan
    expected_e_hat: Mapping[str, float]     # kind -> expected e_hat [N]

    @property
    def pressing_s(self) -> float:
        return sum(n * self.plates * self.session_s[k] for k, n in self.arrays.items())

    @property
    def mean_e_hat(self) -> float:
        """The whole hand's expected e_hat: the mean over its arrays."""
        return sum(n * self.expected_e_hat[k] for k, n in self.arrays.items()) / sum(
            self.arrays.values())


def allocate(budget_s: float, arrays: Mapping[str, int], plates: int, expected: ExpectedError,
             min_session_s: float = MIN_SESSION_S, reserve: float = RESERVE,
             step_s: float = STEP_S) -> Allocation:
    """The session length of each kind (arrays: kind -> how many arrays of it are pressed, on
    `plates` plates each) on a grid of step_s that minimises the whole hand's expected e_hat
    with at most budget_s * (1 - reserve) of pressing. A kind's grid runs from min_session_s, or
    from where its curve begins if later (below its first point the curve says nothing), to
    where its curve ends (beyond it the curve shows no gain)."""
    if plates < 2:
        raise BudgetError(f'{plates} plates: leave-one-plate-out needs two or more')
    if not (min_session_s > 0 and step_s > 0 and 0.0 <= reserve < 1.0):
        raise BudgetError(f'min_session_s {min_session_s} and step_s {step_s} must be > 0, '
                          f'the reserve {reserve} a share of the budget (0 <= r < 1)')
    arrays = {k: int(n) for k, n in arrays.items() if n > 0}
    if not arrays:
        raise BudgetError('a budget plan needs arrays to press')
    missing = sorted(set(arrays) - set(expected.curves))
    if missing:
        raise BudgetError(f'no expected-error curve for {", ".join(missing)} arrays (curves: '
                          f'{sorted(expected.curves)})')
    grids = {}
    for kind in arrays:
        first, last = expected.curves[kind][0][0] / plates, expected.curves[kind][-1][0] / plates
        shortest = step_s * math.ceil(max(min_session_s, first) / step_s - 1e-9)
        grids[kind] = np.arange(shortest, max(shortest, last) + 1e-9, step_s)
    usable = budget_s * (1.0 - reserve)
    least = sum(n * plates * grids[k][0] for k, n in arrays.items())
    if usable < least - 1e-9:
        shortest = ', '.join(f'{k} {grids[k][0]:g} s' for k in arrays)
        raise BudgetError(f'a budget of {budget_s / 60:g} min ({100 * reserve:g} % held back for '
                          f'sessions pressed again) cannot press {sum(arrays.values())} arrays '
                          f'on {plates} plates in the shortest sessions ({shortest}): it needs '
                          f'{least / (1.0 - reserve) / 60:.0f} min or more')
    # Pareto front over kinds: (pressing seconds, sum of expected e_hat, choice), cheapest first.
    front: list[tuple[float, float, dict[str, float]]] = [(0.0, 0.0, {})]
    for kind, n in arrays.items():
        options = [(n * plates * length, n * expected.expected(kind, plates * length)[0],
                    float(length)) for length in grids[kind]]
        grown = [(cost + c, value + v, {**choice, kind: length})
                 for cost, value, choice in front for c, v, length in options
                 if cost + c <= usable + 1e-9]
        grown.sort(key=lambda t: (t[0], t[1]))
        front = []
        for item in grown:
            if not front or item[1] < front[-1][1] - 1e-12:
                front.append(item)
    _, _, choice = min(front, key=lambda t: (t[1], t[0]))
    return Allocation(session_s=choice, plates=plates, arrays=arrays,
                      expected_e_hat={k: expected.expected(k, plates * s)[0]
                                      for k, s in choice.items()})
