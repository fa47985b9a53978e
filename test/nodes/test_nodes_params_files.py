"""Parameters files as users write them: unquoted YAML words that read as booleans (`control:
off`, `force_unit: N`) and a node key that names no node (a misspelt `estimatr:`)."""
import sys
from pathlib import Path

import pytest

from tacforce_ros.nodes.parameters import (ParamSpec, ParameterError, node_key_matches,
                                           params_file_node_keys, params_files)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from ros_processes import OutputLines, executable, start, unique_domain_id  # noqa: E402

DOMAIN = unique_domain_id(offset=73)


def test_a_boolean_read_from_an_unquoted_word_is_the_choice_that_word_names():
    control = ParamSpec('control', 'force', '', choices=('force', 'off'))
    assert control.coerce(False) == 'off'
    unit = ParamSpec('force_unit', 'N', '', choices=('N', 'kN', 'lbf'))
    assert unit.coerce(False) == 'N'
    with pytest.raises(ParameterError, match="control: True is a boolean.*quote the value"):
        control.coerce(True)            # `control: on` names no choice
    with pytest.raises(ParameterError, match="url: False is a boolean.*quote the value"):
        ParamSpec('url', 'ws://127.0.0.1:5000', '').coerce(False)


def test_node_keys_match_as_rcl_matches_them():
    doc = {'estimator': {'ros__parameters': {}}, 'left': {'estimator': {'ros__parameters': {}}},
           '/**': {'ros__parameters': {}}, '/*/recorder': {'ros__parameters': {}}}
    assert params_file_node_keys(doc) == ['/estimator', '/left/estimator', '/**', '/*/recorder']
    assert node_key_matches('estimator', '/estimator')
    assert node_key_matches('/**', '/left/estimator')
    assert node_key_matches('/*/recorder', '/left/recorder')
    assert not node_key_matches('/*/recorder', '/recorder')
    assert not node_key_matches('estimatr', '/estimator')
    assert not node_key_matches('/left/estimator', '/estimator')
    # The shipped files' keys: the node in the root namespace or any other.
    assert node_key_matches('/**/estimator', '/estimator')
    assert node_key_matches('/**/estimator', '/left/estimator')
    assert node_key_matches('/**/estimator', '/rig/left/estimator')
    assert not node_key_matches('/**/estimator', '/left/estimator_2')
    assert not node_key_matches('/**/estimator', '/left_estimator')
    assert params_files(['x', '--ros-args', '-p', 'a:=1', '--params-file', 'f.yaml', '--',
                         '--params-file', 'not_ros.yaml']) == [Path('f.yaml')]


def node_output(name: str, params: Path, text: str) -> tuple[bool, str]:
    """Start node `name` with `params`; whether it printed `text` within 60 s, and its output."""
    out = OutputLines(start([executable(name), '--ros-args', '--params-file', params], DOMAIN))
    try:
        found = out.wait_for(text, 60.0) is not None
    finally:
        output = out.stop()
    return found, output


@pytest.mark.ros
def test_an_unquoted_word_in_a_params_file_starts_the_node(tmp_path):
    params = tmp_path / 'ft_bridge.yaml'
    params.write_text('ft_bridge:\n  ros__parameters:\n    host: 127.0.0.1\n    port: 1\n'
                      '    force_unit: N\n')
    started, text = node_output('ft_bridge', params, 'reading udp 127.0.0.1:1')
    assert started and 'refusing' not in text, text[-1500:]


@pytest.mark.ros
def test_a_params_file_that_names_no_such_node_is_reported(tmp_path):
    params = tmp_path / 'estimator.yaml'
    params.write_text('estimatr:\n  ros__parameters:\n    marker_rate_hz: 0.0\n')
    warned, text = node_output('estimator', params, 'no entry for this node (/estimator)')
    assert warned, text[-1500:]
    assert "did you mean '/estimator' for '/estimatr'" in text and 'runs on defaults' in text


def test_a_frame_prefix_is_one_tf2_can_use():
    from tacforce_ros.nodes.parameters import FRAME_PREFIX
    for good in ('', 'left/', 'rig_2/left/', 'left_'):
        assert FRAME_PREFIX.coerce(good) == good
    for bad in ('/left/', 'left hand/', 'left:'):
        with pytest.raises(ParameterError, match='is not a frame-id prefix'):
            FRAME_PREFIX.coerce(bad)
