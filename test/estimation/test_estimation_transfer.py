"""A model applied unadapted to another array of its kind (cross_validation.transfer): judged
fold by fold as the array's own, so on its own data it is cross_validate, and on an array whose
taxels read otherwise it errs more."""
import numpy as np
import pytest

from tacforce_ros.estimation.cross_validation import cross_validate, transfer

HYPER = {'lam': 1e-3, 'lambda_grid': None}


def test_transfer_to_its_own_data_is_its_cross_validation(tip, tip_data):
    data, X, F, _ = tip_data
    own = cross_validate(tip, 'M3-lambda', HYPER, X, F, data.plates).summary()
    moved = transfer(tip, 'M3-lambda', HYPER, X, F, data.plates,
                     {'itself': (X, F, data.plates)})['itself'].summary()
    assert moved['e_hat_mean'] == pytest.approx(own['e_hat_mean'], rel=1e-12)
    assert [f['test_plate'] for f in moved['per_fold']] == \
        [f['test_plate'] for f in own['per_fold']]


def test_an_array_whose_taxels_read_otherwise_gets_a_larger_error(tip, tip_data):
    data, X, F, _ = tip_data
    gains = 1.5 * np.random.default_rng(3).lognormal(0.0, 0.1, X.shape[1:])  # a softer module
    result = transfer(tip, 'M3-lambda', HYPER, X, F, data.plates,
                      {'same': (X, F, data.plates), 'other': (X * gains, F, data.plates)})
    assert result['other'].summary()['e_hat_mean'] > 1.2 * result['same'].summary()['e_hat_mean']


def test_a_target_without_a_plate_of_the_source_is_refused(tip, tip_data):
    data, X, F, _ = tip_data
    keep = data.plates != data.plates[0]
    with pytest.raises(ValueError, match=f'short has no data on the plate {data.plates[0]}'):
        transfer(tip, 'M3-lambda', HYPER, X, F, data.plates,
                 {'short': (X[keep], F[keep], data.plates[keep])})
