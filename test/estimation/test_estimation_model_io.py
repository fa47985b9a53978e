"""Model files: exact round trip, no pickle, and clear refusals of mismatched or damaged files."""
import json
import zipfile

import numpy as np
import pytest

from tacforce_ros.estimation.model_io import (ModelFileError, load_model, read_header,
                                              save_model)
from tacforce_ros.estimation.training import fit_bundle

PROVENANCE = {'dataset': ['synthetic'], 'plates': ['a', 'b'], 'samples': 10, 'date': 'today',
              'seed': 0, 'code_version': 'test', 'metrics': None}


@pytest.fixture(scope='module', params=['M1', 'M2', 'M3', 'M3-lambda'])
def saved(request, tmp_path_factory, tip, tip_data):
    data, X, F, offset = tip_data
    bundle = fit_bundle(tip, request.param, {}, X, F, data.plates, x_offset=offset,
                        provenance=PROVENANCE)
    path = save_model(tmp_path_factory.mktemp('models') / f'{request.param}.npz', bundle)
    return bundle, path, data


def test_round_trip_predicts_identically(saved, tip):
    bundle, path, data = saved
    loaded = load_model(path, tip)
    counts = data.X[:50]
    np.testing.assert_array_equal(loaded.predict(counts), bundle.predict(counts))
    header = read_header(path)
    assert header['array'] == 'index_tip' and header['n_taxels'] == 30
    assert header['kind'] == bundle.model.kind and header['module_code'] == tip.module_code
    assert header['provenance']['code_version'] == 'test'
    with np.load(path, allow_pickle=False) as npz:    # loadable without pickle
        assert not any(npz[k].dtype == object for k in npz.files)


def test_wrong_array_is_refused(saved, hand):
    _, path, _ = saved
    with pytest.raises(ModelFileError, match="for array 'index_tip', not 'middle_tip'"):
        load_model(path, hand.array('middle_tip'))


def test_a_right_hand_model_is_refused_for_the_left_hands_array(saved, tip, tmp_path):
    from tacforce_ros.hand.description import hand_config, load_hand
    _, path, _ = saved
    assert read_header(path)['hand_side'] == 'right'
    left_tip = load_hand(hand_config('left')).array('index_tip')
    with pytest.raises(ModelFileError, match="for the right hand's index_tip, not the left"):
        load_model(path, left_tip)
    # A file from before the left hand existed (no hand_side) is a right-hand model.
    older = rewrite(path, tmp_path, lambda h, a: h.pop('hand_side'))
    load_model(older, tip)
    with pytest.raises(ModelFileError, match="for the right hand's index_tip"):
        load_model(older, left_tip)


def rewrite(path, tmp_path, edit):
    """Copy of a model file with its entries edited by edit(header, arrays)."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    header = json.loads(str(arrays.pop('header')))
    edit(header, arrays)
    out = tmp_path / 'edited.npz'
    np.savez(out, header=np.array(json.dumps(header)), **arrays)
    return out


def test_taxel_count_mismatch_is_refused(saved, tip, tmp_path):
    _, path, _ = saved
    bad = rewrite(path, tmp_path, lambda h, a: h.update(n_taxels=16))
    with pytest.raises(ModelFileError, match="16 taxels, array 'index_tip' has 30"):
        load_model(bad, tip)


def test_unknown_kind_is_refused(saved, tip, tmp_path):
    _, path, _ = saved
    bad = rewrite(path, tmp_path, lambda h, a: h.update(kind='M9'))
    with pytest.raises(ModelFileError, match="unknown model kind 'M9'"):
        load_model(bad, tip)


def test_missing_entry_is_refused(saved, tip, tmp_path):
    _, path, _ = saved
    bad = rewrite(path, tmp_path, lambda h, a: a.pop('x_std'))
    with pytest.raises(ModelFileError, match="'x_std'"):
        load_model(bad, tip)
    bad = rewrite(path, tmp_path, lambda h, a: h.pop('provenance'))
    with pytest.raises(ModelFileError, match="lacks 'provenance'"):
        load_model(bad, tip)


def test_changed_values_fail_the_checksum(saved, tip, tmp_path):
    _, path, _ = saved
    bad = rewrite(path, tmp_path, lambda h, a: a.update(f_mean=a['f_mean'] + 1.0))
    with pytest.raises(ModelFileError, match="'f_mean' is corrupted"):
        load_model(bad, tip)


def test_damaged_and_foreign_files_are_refused(saved, tip, tmp_path):
    _, path, _ = saved
    raw = path.read_bytes()
    truncated = tmp_path / 'truncated.npz'
    truncated.write_bytes(raw[:len(raw) // 2])
    with pytest.raises(ModelFileError, match='not a readable npz'):
        load_model(truncated, tip)
    flipped = bytearray(raw)
    flipped[len(raw) // 3] ^= 0xFF
    damaged = tmp_path / 'damaged.npz'
    damaged.write_bytes(bytes(flipped))
    with pytest.raises(ModelFileError):
        load_model(damaged, tip)
    foreign = tmp_path / 'foreign.npz'
    np.savez(foreign, weights=np.ones(3))
    with pytest.raises(ModelFileError, match='no header'):
        load_model(foreign, tip)
    with pytest.raises(ModelFileError, match='no such model file'):
        load_model(tmp_path / 'absent.npz', tip)
    pickled = tmp_path / 'pickled.npz'
    with zipfile.ZipFile(pickled, 'w') as archive:
        archive.writestr('header.npy', b'not npy')
    with pytest.raises(ModelFileError):
        load_model(pickled, tip)


def test_provenance_is_required(tip, tip_data, tmp_path):
    data, X, F, offset = tip_data
    bundle = fit_bundle(tip, 'M1', {}, X, F, data.plates, provenance={'seed': 1})
    with pytest.raises(ValueError, match='provenance lacks'):
        save_model(tmp_path / 'm.npz', bundle)


def test_non_finite_entries_with_matching_checksums_are_refused(saved, tip, tmp_path):
    """A training that diverged writes NaN weights with a consistent checksum."""
    from tacforce_ros.estimation.model_io import _sha256
    _, path, _ = saved
    name = next(k for k in read_header(path)['sha256'] if k.startswith('state.'))

    def poison(header, arrays):
        arrays[name] = arrays[name].astype(np.float64)
        arrays[name].flat[0] = np.nan
        header['sha256'][name] = _sha256(arrays[name])
    bad = rewrite(path, tmp_path, poison)
    with pytest.raises(ModelFileError, match=f"entry '{name}' holds 1 of .* values NaN or Inf"):
        load_model(bad, tip)
