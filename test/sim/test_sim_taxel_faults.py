"""Faulty taxels in the simulator (opt-in per scene): a stuck taxel keeps its reading, a dead one
reads 0, a clipped channel reads the end of the 16-bit range, from the moment the fault begins,
and nothing else in the frame changes. Fed to the estimator's model set, each makes its array's
estimate invalid with a status naming the taxel, and leaves the other 17 arrays as they were."""
import dataclasses
import warnings

import numpy as np
import pytest
from conftest import stack

from tacforce_ros.estimation.model_set import default_model_config, load_model_set
from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim.scene import SceneError

TIP = 'calibration_index_tip_spherical'
AT = 1.0                        # s: the fault begins here
FAULTS = {'stuck': {'kind': 'stuck'}, 'dead': {'kind': 'dead'},
          'clipped': {'kind': 'clipped', 'axis': 'y', 'rail': 'high'}}


def run(hand, fault: dict | None, steps: int = 300, seed: int = 3):
    scene = load_scene(TIP)
    effects = dict(scene.effects)
    if fault is not None:
        effects['taxel_faults'] = {'faults': [{'array': 'index_middle', 'taxel': 4, 'at': AT,
                                              **fault}]}
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        sim = make_simulator(dataclasses.replace(scene, effects=effects), hand, seed=seed)
    return [sim.step() for _ in range(steps)]


@pytest.mark.parametrize('kind', sorted(FAULTS))
def test_a_faulty_taxel_reads_as_its_kind_and_nothing_else_changes(hand, kind):
    faulty, healthy = run(hand, FAULTS[kind]), run(hand, None)
    counts, reference = stack(faulty, 'taxel_counts'), stack(healthy, 'taxel_counts')
    t = stack(faulty, 't')
    row = int(hand.array('index_middle').flat_indices[4])
    others = np.arange(hand.n_taxels) != row
    np.testing.assert_array_equal(counts[:, others], reference[:, others])
    before, after = t < AT, t >= AT
    np.testing.assert_array_equal(counts[before, row], reference[before, row])
    if kind == 'stuck':
        assert (counts[after, row] == counts[after, row][0]).all()
        assert np.ptp(reference[after, row].astype(float), axis=0).max() > 0   # it would move
    elif kind == 'dead':
        assert (counts[after, row] == 0).all()
    else:
        assert (counts[after, row, 1] == 65535).all()
        np.testing.assert_array_equal(counts[after, row][:, [0, 2]],
                                      reference[after, row][:, [0, 2]])


@pytest.mark.parametrize('kind', sorted(FAULTS))
def test_the_estimator_names_the_faulty_taxel_and_keeps_the_other_arrays(hand, kind):
    """The shipped models on every array, tared on the first frames, the check on as the
    estimator node runs it: from the fault on (a stuck taxel once it has been still for the
    frozen window), index_middle is invalid and names taxel 4; the 17 other arrays' estimates
    are those of the same run without the fault."""
    frames = stack(run(hand, FAULTS[kind], steps=400), 'taxel_counts')
    reference_frames = stack(run(hand, None, steps=400), 'taxel_counts')
    checked = load_model_set(default_model_config(hand), hand)
    plain = load_model_set(default_model_config(hand), hand)
    for models in (checked, plain):
        models.set_tare(reference_frames[:50].astype(np.float64))
    checked.check_taxels()
    k = [a.name for a in checked.arrays].index('index_middle')
    others = np.arange(len(checked.arrays)) != k
    statuses = []
    for frame, reference in zip(frames[50:], reference_frames[50:]):
        got, expected = checked.estimate(frame), plain.estimate(reference)
        np.testing.assert_array_equal(got.force[others], expected.force[others])
        assert got.valid[others].all()
        statuses.append(got.status[k])
    named = {'stuck': 'taxel 4 frozen', 'dead': 'taxel 4 clipped (reads 0)',
             'clipped': 'taxel 4 clipped (reads 65535)'}[kind]
    assert statuses[-1] == named and not got.valid[k]
    assert set(statuses) <= {'ok', named}


@pytest.mark.parametrize('fault, message', [
    ({'array': 'index_middle', 'taxel': 4, 'kind': 'melted'}, 'kind'),
    ({'array': 'index_middle', 'kind': 'dead'}, 'missing'),
    ({'array': 'index_middle', 'taxel': 4, 'kind': 'clipped', 'axis': 'w'}, 'axis'),
    ({'array': 'index_middle', 'taxel': 4, 'kind': 'dead', 'colour': 1}, 'unknown keys')])
def test_a_fault_the_simulator_cannot_make_is_refused_naming_the_field(tmp_path, fault, message):
    import yaml
    path = tmp_path / 'faulty.yaml'
    path.write_text(yaml.safe_dump({'extends': TIP,
                                    'effects': {'taxel_faults': {'faults': [fault]}}}))
    with pytest.raises(SceneError, match=f'effects.taxel_faults.*{message}'):
        load_scene(path)


def test_a_taxel_the_array_does_not_have_is_refused_at_start(hand):
    scene = load_scene(TIP)
    effects = {**scene.effects, 'taxel_faults': {'faults': [
        {'array': 'index_middle', 'taxel': 16, 'kind': 'dead'}]}}
    with pytest.raises(ValueError, match='index_middle has 16 taxels'):
        make_simulator(dataclasses.replace(scene, effects=effects), hand, seed=0)
