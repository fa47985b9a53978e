"""The package's rooms: ROS only in nodes/, command-line tools only in tools/ (nothing else
imports them), the estimator's model set with the estimation core."""
import ast
from pathlib import Path

import tacforce_ros

ROOT = Path(tacforce_ros.__file__).resolve().parent


def imports(path: Path) -> set[str]:
    """Every module a source file imports, function bodies included."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
    return found


def modules_importing(predicate) -> list[str]:
    return sorted(str(p.relative_to(ROOT)) for p in ROOT.rglob('*.py')
                  if any(predicate(name) for name in imports(p)))


def test_only_nodes_import_rclpy():
    users = modules_importing(lambda name: name.split('.')[0] == 'rclpy')
    assert users and all(u.startswith('nodes/') for u in users), users


def test_nothing_outside_tools_imports_tools():
    users = modules_importing(lambda name: name.startswith('tacforce_ros.tools'))
    assert all(u.startswith('tools/') for u in users), users


def test_the_model_set_lives_with_the_estimation_core():
    assert (ROOT / 'estimation' / 'model_set.py').is_file()
    assert not list((ROOT / 'nodes').glob('model_set*'))
    assert 'rclpy' not in {n.split('.')[0] for n in imports(ROOT / 'estimation' / 'model_set.py')}


def test_topic_names_are_spelled_only_in_topics():
    """Every topic name is a constant of tacforce_ros/topics.py (docstrings may mention them)."""
    prefixes = ('/tactile', '/ft_sensor', '/joint_states', '/calibration', '/session', '/sim/',
                '/force_controller', '/allegro_driver', '/diagnostics')
    spelled = []
    for path in ROOT.rglob('*.py'):
        if path.name == 'topics.py' and path.parent == ROOT:
            continue
        tree = ast.parse(path.read_text(), str(path))
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)}
        spelled += [f'{path.relative_to(ROOT)}:{node.lineno}: {node.value}'
                    for node in ast.walk(tree)
                    if isinstance(node, ast.Constant) and isinstance(node.value, str)
                    and node.value.startswith(prefixes) and id(node) not in docstrings]
    assert not spelled, spelled
