"""The hand description: counts, mapping, taxel frames, validation and split/merge."""
from collections import Counter

import numpy as np
import pytest
import yaml
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from tacforce_ros.hand.description import HandConfigError, load_hand
from tacforce_ros.paths import config_dir

CONFIG = config_dir() / 'hand' / 'allegro_right_uskin.yaml'
HAND = load_hand()


def test_counts_per_kind_and_total():
    kinds = Counter(a.kind for a in HAND.arrays)
    assert kinds == {'fingertip': 4, 'phalanx': 11, 'palm': 3}
    for a in HAND.arrays:
        assert a.n_taxels == {'fingertip': 30, 'phalanx': 16, 'palm': 24}[a.kind], a.name
        assert a.positions.shape == (a.n_taxels, 3)
        assert a.rotations.shape == (a.n_taxels, 3, 3)
        assert a.flat_indices.shape == (a.n_taxels,)
    assert HAND.n_taxels == sum(a.n_taxels for a in HAND.arrays) == 368
    assert [a.name for a in HAND.arrays if a.finger == 'thumb'] == [
        'thumb_tip', 'thumb_distal', 'thumb_proximal']
    assert HAND.array('index_tip').kind == 'fingertip'
    assert HAND.array('index_middle').kind == 'phalanx'


def test_flat_mapping_is_a_permutation():
    flat = np.concatenate([a.flat_indices for a in HAND.arrays])
    assert np.array_equal(np.sort(flat), np.arange(368))


def test_published_scan_order_samples():
    # Entries of invokelshn/xela_apps r_server_model_joint_map.yaml: flat index -> module, taxel no.
    for flat_index, code, taxel_number in [(0, '03', 2), (4, '03', 1), (75, '11', 16),
                                           (119, '51', 19), (238, '52', 6), (367, '33', 30)]:
        owner = next(a for a in HAND.arrays if a.module_code == code)
        assert owner.flat_indices[taxel_number - 1] == flat_index


def test_grid_holds_every_taxel_once():
    for a in HAND.arrays:
        cells = a.grid_index[a.grid_index >= 0]
        assert np.array_equal(np.sort(cells), np.arange(a.n_taxels)), a.name
    tip = HAND.array('index_tip')
    assert tip.grid_index.shape == (6, 6)
    assert (tip.grid_index >= 0).sum(axis=1).tolist() == [2, 4, 6, 6, 6, 6]
    assert HAND.array('index_middle').grid_index.shape == (4, 4)
    assert HAND.array('palm_center').grid_index.shape == (4, 6)


def test_grid_neighbours_are_one_pitch_apart_on_flat_pads():
    for name in ('index_middle', 'palm_index_side'):
        a = HAND.array(name)
        g = a.grid_index
        right = np.linalg.norm(a.positions[g[:, 1:]] - a.positions[g[:, :-1]], axis=-1)
        down = np.linalg.norm(a.positions[g[1:, :]] - a.positions[g[:-1, :]], axis=-1)
        np.testing.assert_allclose(right, 0.0047, atol=1e-12)
        np.testing.assert_allclose(down, 0.0047, atol=1e-12)
        np.testing.assert_allclose(a.positions.mean(axis=0), 0.0, atol=1e-12)


def test_taxel_frames_are_proper_rotations():
    for a in HAND.arrays:
        R = a.rotations
        np.testing.assert_allclose(np.einsum('nji,njk->nik', R, R),
                                   np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


def test_flat_pads_identity_curved_tips_follow_the_surface():
    for a in HAND.arrays:
        if a.kind == 'fingertip':
            normals = a.rotations[:, :, 2]
            g = a.grid_index
            # Around the finger every column faces another way; along it the cap rows tilt
            # more and more distally, the cylinder rows share their column's normal.
            row3 = normals[g[3]]
            assert np.all(np.abs(row3 @ row3.T - np.eye(6)).max(axis=1) < 1 - 1e-3), a.name
            for col in (2, 3):
                tilt = normals[g[:, col], 0]
                on_cap = tilt > 0
                assert on_cap.any() and not on_cap.all(), a.name
                assert np.all(np.diff(tilt[on_cap]) < 0), a.name
                cylinder = normals[g[~on_cap, col]]
                np.testing.assert_allclose(cylinder, cylinder[:1].repeat(len(cylinder), 0),
                                           atol=1e-12)
            # z of each taxel is the outward normal: the position's direction from the cap
            # centre (cap) or from the finger axis (cylinder), with a constant radius.
            radial = a.positions.copy()
            radial[:, 0] = np.clip(radial[:, 0], 0.0, None)
            radius = np.linalg.norm(radial, axis=1)
            np.testing.assert_allclose(radius, radius[0], rtol=1e-12)
            np.testing.assert_allclose(radial / radius[:, None], normals, atol=1e-12)
        else:
            np.testing.assert_array_equal(a.rotations,
                                          np.broadcast_to(np.eye(3), a.rotations.shape))
            np.testing.assert_array_equal(a.positions[:, 2], 0.0)


def test_neighbours_are_mutual_and_known():
    names = {a.name for a in HAND.arrays}
    for a in HAND.arrays:
        assert a.neighbours, a.name
        for other in a.neighbours:
            assert other in names and a.name in HAND.array(other).neighbours


def test_arrays_are_immutable():
    a = HAND.array('index_tip')
    with pytest.raises(ValueError):
        a.positions[0, 0] = 1.0
    with pytest.raises(AttributeError):
        a.name = 'x'


def test_unknown_name_is_a_clear_key_error():
    with pytest.raises(KeyError, match='no taxel array named'):
        HAND.array('pinky_tip')


@settings(max_examples=40, deadline=None)
@given(lead=st.lists(st.integers(1, 3), max_size=2), k=st.integers(1, 4),
       seed=st.integers(0, 2**31))
def test_split_merge_round_trip(lead, k, seed):
    flat = np.random.default_rng(seed).normal(size=(*lead, 368, k))
    parts = HAND.split(flat)
    assert [p.shape for p in parts] == [(*lead, a.n_taxels, k) for a in HAND.arrays]
    for part, a in zip(parts, HAND.arrays):
        np.testing.assert_array_equal(part, flat[..., a.flat_indices, :])
    np.testing.assert_array_equal(HAND.merge(parts), flat)


@given(arrays(np.int32, (368, 3)))
def test_merge_split_round_trip_integers(raw):
    np.testing.assert_array_equal(HAND.merge(HAND.split(raw)), raw)


def test_split_and_merge_refuse_wrong_shapes():
    with pytest.raises(ValueError, match='368'):
        HAND.split(np.zeros((367, 3)))
    parts = HAND.split(np.zeros((368, 3)))
    with pytest.raises(ValueError, match='index_tip'):
        HAND.merge([np.zeros((29, 3))] + parts[1:])
    with pytest.raises(ValueError, match='18 arrays'):
        HAND.merge(parts[:-1])


# ---------------------------------------------------------------- malformed copies are refused

def _broken(tmp_path, mutate):
    doc = yaml.safe_load(CONFIG.read_text())
    mutate(doc)
    (tmp_path / 'hand').mkdir()
    path = tmp_path / 'hand' / 'broken.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


def _swap_first_flat(doc):
    doc['arrays'][1]['flat_indices'][0] = doc['arrays'][0]['flat_indices'][0]


def _skewed_rotations(doc):
    spec = doc['modules']['uSPa44']
    spec['positions'] = [[0.0, 0.0, 0.0]] * 16
    spec['rotations'] = [[[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]] * 16


BROKEN = {
    'missing key': (lambda d: d['arrays'][2].pop('parent_link'),
                    r'arrays\[2\] \(index_middle\)\.parent_link: missing key'),
    'wrong count': (lambda d: d['arrays'][0].update(n_taxels=29),
                    r'index_tip\)\.n_taxels: 29 .* 30 taxels'),
    'short mapping': (lambda d: d['arrays'][0]['flat_indices'].pop(),
                      r'index_tip\)\.flat_indices: need 30'),
    'duplicate flat index': (_swap_first_flat,
                             r'index_distal\)\.flat_indices: 66 duplicates .*index_tip'),
    'out of range': (lambda d: d['arrays'][3]['flat_indices'].__setitem__(0, 368),
                     r'index_proximal\)\.flat_indices: 368 outside'),
    'unknown neighbour': (lambda d: d['arrays'][0].update(neighbours=['pinky_tip']),
                          r'index_tip\)\.neighbours: unknown array .pinky_tip'),
    'one-sided neighbour': (lambda d: d['arrays'][0]['neighbours'].append('ring_tip'),
                            r'does not list'),
    'grid mismatch': (lambda d: d['modules']['uSPa44']['grid'].pop(),
                      r'index_distal\)\.n_taxels: 16 but module uSPa44 grid has 12'),
    'bad grid numbers': (lambda d: d['modules']['uSPa46']['grid'][0].__setitem__(0, 7),
                         r'modules\.uSPa46\.grid'),
    'non-orthonormal rotation': (_skewed_rotations,
                                 r'rotations \(module uSPa44\): not proper rotations'),
    'unknown module': (lambda d: d['arrays'][5].update(module='uSPa99'),
                       r'middle_distal\)\.module: unknown'),
    'finger on palm': (lambda d: d['arrays'][-1].update(finger='index'),
                       r'palm_ring_side\)\.finger'),
    'duplicate name': (lambda d: d['arrays'][1].update(name='index_tip'), r'name: duplicates'),
    'bad pitch': (lambda d: d['modules']['uSCuAH'].update(pitch=0), r'modules\.uSCuAH\.pitch'),
    'missing top-level': (lambda d: d.pop('ft_frame'), r'ft_frame: missing key'),
    'unknown side': (lambda d: d.update(side='both'), r"side: 'both' is not one of"),
}


@pytest.mark.parametrize('case', sorted(BROKEN))
def test_malformed_config_is_refused_naming_the_field(tmp_path, case):
    mutate, message = BROKEN[case]
    path = _broken(tmp_path, mutate)
    with pytest.raises(HandConfigError, match=message):
        load_hand(path)


def test_unmodified_copy_loads(tmp_path):
    hand = load_hand(_broken(tmp_path, lambda d: None))
    assert hand.n_taxels == 368
    assert hand.urdf_path == (tmp_path / 'urdf' / 'allegro_right_uskin.urdf').resolve()
