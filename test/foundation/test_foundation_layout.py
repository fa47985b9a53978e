"""The package's rooms: ROS only in nodes/; the runtime (everything but experiments/ and
benchmarks/) never imports the experiments or the benchmarks; no command imports another and none
is started by its module's name; the estimator's model set with the estimation core."""
import ast
import re
from importlib.metadata import entry_points
from pathlib import Path

import tacforce_ros

ROOT = Path(tacforce_ros.__file__).resolve().parent
APART = ('experiments', 'benchmarks')       # what the runtime must not import


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


def test_the_runtime_imports_neither_experiments_nor_benchmarks():
    apart = tuple(f'tacforce_ros.{room}' for room in APART)
    users = modules_importing(lambda name: name.startswith(apart))
    runtime_users = [u for u in users if u.split('/')[0] not in APART]
    assert users and not runtime_users, runtime_users
    launch = Path(__file__).resolve().parents[2] / 'launch'
    for path in launch.glob('*.py'):
        assert not any(name.startswith(apart) for name in imports(path)), path


def command_modules() -> dict[str, str]:
    """Every installed executable of the package: its module."""
    return {ep.module: ep.name for ep in entry_points(group='console_scripts')
            if ep.module.startswith('tacforce_ros.')}


def test_no_command_imports_another():
    commands = command_modules()
    assert {'train', 'session', 'reproduce', 'bench_stop'} <= set(commands.values()), commands
    crossing = []
    for module in commands:
        path = ROOT.joinpath(*module.split('.')[1:]).with_suffix('.py')
        crossing += [f'{module} imports {name}' for name in imports(path)
                     if name in commands and name != module]
    assert not crossing, crossing


def test_no_process_is_started_by_a_module_name():
    """`python -m tacforce_ros...` or a dotted module name handed to a subprocess: the installed
    executable (bringup.processes.executable) serves, as a user would start it."""
    dotted = re.compile(r'^tacforce_ros(\.\w+)+$')
    found = []
    for path in ROOT.rglob('*.py'):
        tree = ast.parse(path.read_text(), str(path))
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                    and id(node) not in docstrings and dotted.match(node.value):
                found.append(f'{path.relative_to(ROOT)}:{node.lineno}: {node.value}')
    assert not found, found


def test_the_session_plan_is_bring_up_not_a_node():
    assert (ROOT / 'bringup' / 'session_plan.py').is_file()
    assert 'rclpy' not in {n.split('.')[0] for n in imports(ROOT / 'bringup' / 'session_plan.py')}


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
