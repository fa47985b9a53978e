"""A campaign with a budget (recording/budget.py): the budget's text, the expected-error curves,
and an allocation that is the best the grid offers within the budget."""
import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.recording.budget import (BudgetError, ExpectedError, allocate, parse_budget)

CURVES = ExpectedError({'fingertip': ((100.0, 0.9), (400.0, 0.4), (1000.0, 0.3)),
                        'phalanx': ((100.0, 0.35), (400.0, 0.3), (1000.0, 0.28))})


@pytest.mark.parametrize('text, seconds', [('60m', 3600.0), ('1.5h', 5400.0), ('3600s', 3600.0),
                                           ('3600', 3600.0), (' 90 m ', 5400.0)])
def test_a_budget_reads_as_hours_minutes_or_seconds(text, seconds):
    assert parse_budget(text) == seconds


@pytest.mark.parametrize('text', ['', 'an hour', '60 min', '-5m', '0m', '1e3'])
def test_a_budget_that_is_not_a_duration_is_refused(text):
    with pytest.raises(BudgetError, match='budget'):
        parse_budget(text)


def test_the_curve_is_exact_at_its_points_log_log_between_and_held_at_its_ends():
    assert CURVES.expected('fingertip', 400.0) == (0.4, 0)
    # Halfway in log seconds is halfway in log error: the geometric means.
    value, side = CURVES.expected('fingertip', 200.0)
    assert side == 0 and value == pytest.approx(math.sqrt(0.9 * 0.4))
    assert CURVES.expected('fingertip', 50.0) == (0.9, -1)          # a lower bound
    assert CURVES.expected('fingertip', 5000.0) == (0.3, 1)         # an upper bound
    with pytest.raises(BudgetError, match='no expected-error curve for palm'):
        CURVES.expected('palm', 100.0)
    assert ExpectedError.from_dict(CURVES.to_dict()) == CURVES


def test_the_curves_are_the_kinds_means_of_the_kind_curve_rows():
    rows = [{'array': a, 'kind': 'phalanx', 'seconds': s, 'e_hat_n': e, 'way': 'shared-kind'}
            for a, s, e in (('a', 100, 0.3), ('b', 100, 0.5), ('a', 200, 0.2), ('b', 200, 0.4))]
    rows.append({'array': 'a', 'kind': 'phalanx', 'seconds': 100, 'e_hat_n': 9.0, 'way': 'own'})
    curves = ExpectedError.from_rows(rows, 'test')
    assert curves.curves == {'phalanx': ((100.0, pytest.approx(0.4)),
                                         (200.0, pytest.approx(0.3)))}
    with pytest.raises(BudgetError, match='no kind-curve rows'):
        ExpectedError.from_rows(rows[-1:])
    assert not curves.pooled
    pooled = ExpectedError.from_rows([{**r, 'way': 'shared-kind+pool'} for r in rows[:-1]])
    assert pooled.pooled and ExpectedError.from_dict(pooled.to_dict()) == pooled
    with pytest.raises(BudgetError, match='with and without'):
        ExpectedError.from_rows(rows[:1] + [{**rows[1], 'way': 'shared-kind+pool'}])
    for bad in ({'x': ()}, {'x': ((200.0, 0.3), (100.0, 0.4))}, {'x': ((100.0, -0.1),)}):
        with pytest.raises(BudgetError, match='increasing seconds'):
            ExpectedError(bad)


def test_the_steeper_kind_gets_the_longer_sessions_within_the_budget():
    arrays = {'fingertip': 4, 'phalanx': 11}
    allocation = allocate(3600.0, arrays, 5, CURVES, min_session_s=10.0)
    assert allocation.pressing_s <= 3600.0
    assert allocation.session_s['fingertip'] > allocation.session_s['phalanx']
    uniform = 3600.0 / (15 * 5)
    flat = sum(n * CURVES.expected(k, 5 * uniform)[0] for k, n in arrays.items()) / 15
    assert allocation.mean_e_hat < flat


def test_a_budget_too_small_for_the_shortest_sessions_says_what_it_needs():
    with pytest.raises(BudgetError, match=r'a budget of 30 min \(5 % held back .* needs 39 min'):
        allocate(1800.0, {'fingertip': 4, 'phalanx': 11}, 5, CURVES, min_session_s=30.0)
    # Below its first point a curve says nothing: no session is planned shorter than that.
    assert allocate(3600.0, {'phalanx': 11}, 5, CURVES, min_session_s=5.0).session_s[
        'phalanx'] >= 100.0 / 5
    with pytest.raises(BudgetError, match='needs arrays'):
        allocate(3600.0, {'palm': 0}, 5, CURVES)
    with pytest.raises(BudgetError, match='two or more'):
        allocate(3600.0, {'fingertip': 4}, 1, CURVES)
    with pytest.raises(BudgetError, match='no expected-error curve for palm'):
        allocate(3600.0, {'palm': 3}, 5, CURVES)


curve = st.lists(st.floats(0.05, 2.0), min_size=2, max_size=4).map(
    lambda es: tuple((100.0 * 2 ** i, e) for i, e in enumerate(sorted(es, reverse=True))))


@settings(max_examples=40, deadline=None)
@given(tips=curve, pads=curve, n_tips=st.integers(1, 4), n_pads=st.integers(1, 11),
       budget=st.floats(400.0, 20000.0))
def test_the_allocation_is_the_best_the_grid_offers_within_the_budget(tips, pads, n_tips,
                                                                      n_pads, budget):
    curves = ExpectedError({'fingertip': tips, 'phalanx': pads})
    # The curves begin at 100 s, 50 s a session on two plates: the shortest session.
    arrays, plates, step, least = {'fingertip': n_tips, 'phalanx': n_pads}, 2, 25.0, 50.0
    if budget < (n_tips + n_pads) * plates * least:
        with pytest.raises(BudgetError):
            allocate(budget, arrays, plates, curves, least, 0.0, step)
        return
    allocation = allocate(budget, arrays, plates, curves, least, 0.0, step)
    assert allocation.pressing_s <= budget + 1e-6
    # Every pair of lengths on the grid that fits costs at least as much expected error.
    grids = {k: [least + step * i for i in range(int((max(least, v[-1][0] / plates) - least)
                                                     / step + 1e-9) + 1)]
             for k, v in curves.curves.items()}
    for tip_s, pad_s in itertools.product(grids['fingertip'], grids['phalanx']):
        if (n_tips * tip_s + n_pads * pad_s) * plates <= budget:
            value = (n_tips * curves.expected('fingertip', plates * tip_s)[0]
                     + n_pads * curves.expected('phalanx', plates * pad_s)[0]) / (n_tips + n_pads)
            assert allocation.mean_e_hat <= value + 1e-9
