"""docs/PARAMETERS.md written from the nodes' own declarations (each node's PARAMETERS, the
ParamSpecs it declares, validates and prints with --help), as generate_parameter_library
documents a controller from its one YAML. The suite checks the page is current
(test_foundation_parameters_page); after changing a declaration, write it again with
`./run.sh exec python -m tacforce_ros.nodes.parameters_page`."""
from __future__ import annotations

import importlib
import sys
from pathlib import Path

from tacforce_ros.nodes.node_base import TacforceNode
from tacforce_ros.nodes.parameters import ParamSpec

# Nodes in the order a session starts them (tacforce_container composes these, with no own).
NODE_MODULES = ('sim_world', 'xela_driver', 'ft_bridge', 'allegro_driver', 'estimator',
                'force_controller', 'command_player', 'grasp_controller', 'grasp_client',
                'sync_recorder', 'coverage_view')
PAGE = Path(__file__).resolve().parents[2] / 'docs' / 'PARAMETERS.md'


def node_class(module: str) -> type[TacforceNode]:
    loaded = importlib.import_module(f'tacforce_ros.nodes.{module}')
    found = [value for value in vars(loaded).values()
             if isinstance(value, type) and issubclass(value, TacforceNode)
             and value.__module__ == loaded.__name__]
    if len(found) != 1:
        raise LookupError(f'tacforce_ros.nodes.{module}: {len(found)} node classes, expected 1')
    return found[0]


def _cell(text: str) -> str:
    return text.replace('|', '\\|').replace('\n', ' ')


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f'{value:g}'


def _limits(spec: ParamSpec) -> str:
    if spec.range is not None:
        return f'{_number(spec.range[0])} .. {_number(spec.range[1])}'
    if spec.choices:
        return ', '.join(f'`{c}`' for c in spec.choices)
    if spec.pattern:
        return _cell(spec.pattern[1])
    return ''


def markdown() -> str:
    lines = ['# Node parameters', '',
             'Written by `tacforce_ros/nodes/parameters_page.py` from the declarations each node '
             'declares, checks and prints with `--help`; do not edit by hand. Set them with '
             '`--ros-args -p name:=value`, a `--params-file`, or the launch files '
             '(`config/params/*.yaml` hold the shipped values, with their reasons). A value of '
             'the wrong type or outside its limits is refused at start-up, naming it; '
             'read-only parameters are read once at start-up.', '']
    for module in NODE_MODULES:
        cls = node_class(module)
        summary = (cls.__doc__ or '').strip().split('\n\n')[0].replace('\n', ' ')
        lines += [f'## {cls.NODE_NAME}', '', summary, '',
                  '| parameter | default | limits | writable | what |', '|---|---|---|---|---|']
        lines += [f'| `{s.name}` | `{_cell(repr(s.default))}` | {_limits(s)} | '
                  f'{"" if s.read_only else "yes"} | {_cell(s.description)} |'
                  for s in cls.PARAMETERS]
        lines.append('')
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    PAGE.write_text(markdown())
    print(f'wrote {PAGE}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
