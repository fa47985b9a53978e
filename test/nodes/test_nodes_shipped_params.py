"""The shipped parameter files agree with the one declaration of each node's parameters (its
PARAMETERS table): every key a declared parameter, every value of its type and within its
range, so a file and the code cannot drift apart."""
import pytest
import yaml

from tacforce_ros.control.force_controller import finger_params_file
from tacforce_ros.bringup.session_plan import params_node_key
from tacforce_ros.nodes.parameters_page import NODE_MODULES, node_class
from tacforce_ros.paths import config_dir

ROS_DECLARED = {'use_sim_time'}         # declared by rclpy itself


def flattened(params: dict, prefix: str = '') -> dict:
    """ros__parameters as rcl reads them: nested mappings are dotted names."""
    out = {}
    for key, value in params.items():
        if isinstance(value, dict):
            out.update(flattened(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


# Loaded after a node's own file for one case: a finger's controller (finger_params_file).
OVERLAYS = {finger_params_file('thumb').stem: 'force_controller'}


def test_every_node_has_a_shipped_parameter_file():
    assert sorted(p.stem for p in (config_dir() / 'params').glob('*.yaml')) == sorted(
        [*NODE_MODULES, *OVERLAYS])


@pytest.mark.parametrize('stem, node', [(n, n) for n in sorted(NODE_MODULES)]
                         + sorted(OVERLAYS.items()))
def test_a_shipped_parameter_file_holds_only_declared_parameters_of_valid_values(stem, node):
    doc = yaml.safe_load((config_dir() / 'params' / f'{stem}.yaml').read_text())
    assert list(doc) == [params_node_key(node)]
    values = flattened(doc[params_node_key(node)]['ros__parameters'])
    specs = {spec.name: spec for spec in node_class(node).PARAMETERS}
    undeclared = set(values) - set(specs) - ROS_DECLARED
    assert not undeclared, f'{node}.yaml sets parameters {node} does not declare: {undeclared}'
    for name, value in values.items():
        if name in specs:
            specs[name].coerce(value)     # raises ParameterError naming what is wrong
