import dataclasses
import textwrap
from typing import ClassVar

import pytest

from tacforce_ros.sim import SceneError, list_scenes, load_scene
from tacforce_ros.sim.effects import EFFECTS, Effect, Pipeline


def write(tmp_path, text, name='scene.yaml'):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_every_shipped_scene_loads(hand):
    names = list_scenes()
    plates = {'button', 'flat', 'fillet', 'convex', 'edge', 'spherical'}
    for array in (a.name for a in hand.arrays):    # a calibration scene needs no file
        scenes = [load_scene(f'calibration_{array}_{p}') for p in plates]
        assert {s.plate.name for s in scenes} == plates
        assert {(s.array, s.kind, s.duration) for s in scenes} == {(array, 'calibration', 100.0)}
        assert scenes[0].name == f'calibration_{array}_{scenes[0].plate.name}'
    objects = {load_scene(n).soft_object.name for n in names
               if n.startswith('closed_loop_') and load_scene(n).soft_object}
    assert objects == {'foam_brick', 'softball', 'abrasive_sponge', 'bleach_cleanser'}
    assert load_scene('closed_loop_spherical').soft_object is None


def test_extends_merges_and_null_removes_an_effect(tmp_path):
    path = write(tmp_path, '''
        extends: calibration_index_tip_edge
        seed: 7
        effects: {taxel_noise: null, hysteresis: {relative: 0.1}}
    ''')
    scene = load_scene(path)
    parent = load_scene('calibration_index_tip_edge')
    assert scene.seed == 7 and scene.plate == parent.plate and scene.array == 'index_tip'
    assert 'taxel_noise' not in scene.effects and 'taxel_noise' in parent.effects
    assert scene.effects['hysteresis'] == {'relative': 0.1}


@pytest.mark.parametrize('body, field', [
    ('extends: _calibration\narray: index_tip\n', '"plate"'),
    ('extends: _calibration\narray: index_tip\nplate: banana\n', '"plate"'),
    ('extends: _calibration\narray: index_tip\nplate: flat\nduration: -1\n', '"duration"'),
    ('extends: _calibration\narray: index_tip\nplate: flat\nseed: x\n', '"seed"'),
    ('extends: _calibration\narray: index_tip\nplate: flat\neffects: {warp: {}}\n',
     '"effects.warp"'),
    ('extends: _calibration\narray: index_tip\nplate: flat\neffects: {taxel_noise: {sgma: 1}}\n',
     '"effects.taxel_noise"'),
    ('extends: _base\nkind: dream\n', '"kind"'),
    ('extends: scene\n', '"extends"'),
    ('extends: closed_loop_spherical\nfinger: {pose: [0.0, 0.1]}\n', '"finger.pose"'),
])
def test_bad_scene_names_the_field(tmp_path, body, field):
    with pytest.raises(SceneError, match=field):
        load_scene(write(tmp_path, body))


def test_unknown_scene_lists_the_known_ones():
    with pytest.raises(SceneError, match='closed_loop_spherical.*calibration_<array>_<plate>'):
        load_scene('no_such_scene')
    with pytest.raises(SceneError, match='calibration_index_tip_banana'):   # no such plate
        load_scene('calibration_index_tip_banana')


def test_a_closed_loop_scene_of_another_fingertip_is_the_index_scene_on_that_finger():
    index = load_scene('closed_loop_foam_brick')
    ring = load_scene('closed_loop_ring_tip_foam_brick')
    assert (ring.array, ring.finger['name'], ring.soft_object) == ('ring_tip', 'ring',
                                                                   index.soft_object)
    assert {k: v for k, v in ring.finger.items() if k != 'name'} == {
        k: v for k, v in index.finger.items() if k != 'name'}
    assert ring.effects == index.effects and ring.plate == index.plate
    thumb = load_scene('closed_loop_thumb_tip_spherical')      # its own poses
    assert (thumb.array, thumb.finger['name'], thumb.finger['contact_pose']) == (
        'thumb_tip', 'thumb', [0.9, 0.5, 0.6, 0.5])
    assert thumb.finger['skin_stiffness'] == index.finger['skin_stiffness']
    with pytest.raises(SceneError, match='not found'):             # no such object
        load_scene('closed_loop_ring_tip_banana')


def test_a_closed_loop_scene_refuses_an_array_off_its_finger(hand, tmp_path):
    from tacforce_ros.sim import make_simulator
    scene = load_scene(write(tmp_path, 'extends: closed_loop_spherical\narray: middle_tip\n'))
    with pytest.raises(SceneError, match='middle_tip is not on the pressing finger'):
        make_simulator(scene, hand)


def test_every_effect_has_a_distinct_registered_name():
    assert all(cls.name == name for name, cls in EFFECTS.items())


def test_a_misspelt_hook_fails_loudly():
    @dataclasses.dataclass
    class Misspelt(Effect):
        name: ClassVar[str] = 'misspelt'

        def on_taxelforce(self, state):     # stage 'taxel_force'
            raise AssertionError('never called')

    with pytest.raises(TypeError, match=r"'misspelt': hooks \['on_taxelforce'\] name no stage"):
        Pipeline([Misspelt()])
    # Every shipped hook is known (an effect and those it supersedes never run together).
    superseded = {name for cls in EFFECTS.values() for name in cls.supersedes}
    assert Pipeline([cls() for name, cls in EFFECTS.items() if name not in superseded]).effects
    assert Pipeline([cls() for cls in EFFECTS.values() if not cls.supersedes]).effects


def test_a_press_tour_names_arrays_and_starts_with_its_array(tmp_path):
    tour = load_scene('press_tour')
    assert tour.array == tour.press_tour[0] and len(tour.press_tour) == 18
    with pytest.raises(SceneError, match='"press_tour"'):
        load_scene(write(tmp_path, 'extends: press_tour\npress_tour: index_tip\n'))
    with pytest.raises(SceneError, match='"array" must be the first'):
        load_scene(write(tmp_path, 'extends: press_tour\narray: palm_center\n'))
