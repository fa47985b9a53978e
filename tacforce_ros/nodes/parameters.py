"""A node's parameters: each a `ParamSpec` (name, default, description, range or choices,
read_only), the specs several nodes share, and the check that a --params-file reaches its node.

TacforceNode (nodes/node_base.py) declares them with a full ParameterDescriptor (so `ros2 param
describe` shows the description and range), checks every value at start-up and refuses bad ones
with one message naming each parameter, e.g. ``rate_hz: -5.0 is outside [1.0, 1000.0]``;
run_node logs it and exits with EXIT_BAD_PARAMETERS. An integer given for a float parameter
(``-p rate_hz:=50``) is accepted as that float. Writable (not read_only) parameters are checked
again when changed at run time. The same specs print --help and docs/PARAMETERS.md.
"""
from __future__ import annotations

import difflib
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from tacforce_ros.hand.description import (FRAME_PREFIX_PATTERN, HandConfigError, HandDescription,
                                           load_hand)


class ParameterError(ValueError):
    """Parameter values a node refuses; the message names every offending parameter."""


# Words ROS parameter YAML (rcl_yaml_param_parser, YAML 1.1) reads as booleans when unquoted:
# `control: off` arrives as False, `force_unit: N` as False.
YAML_BOOLEAN_WORDS = {
    True: ('y', 'Y', 'yes', 'Yes', 'YES', 'true', 'True', 'TRUE', 'on', 'On', 'ON'),
    False: ('n', 'N', 'no', 'No', 'NO', 'false', 'False', 'FALSE', 'off', 'Off', 'OFF'),
}


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter. The type is the default's: bool, int, float, str or a list of one."""

    name: str
    default: Any
    description: str
    range: tuple[float, float] | None = None      # inclusive; numbers and number lists
    choices: tuple[str, ...] | None = None        # strings only
    pattern: tuple[str, str] | None = None        # strings only: (regex, what it asks for)
    read_only: bool = True                        # most of ours are read once at start-up

    def descriptor(self) -> ParameterDescriptor:
        desc = ParameterDescriptor(name=self.name, description=self.description,
                                   read_only=self.read_only)
        if self.range is not None and self._scalar_type() is int:
            desc.integer_range = [IntegerRange(from_value=int(self.range[0]),
                                               to_value=int(self.range[1]), step=0)]
        elif self.range is not None:
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(self.range[0]), to_value=float(self.range[1]), step=0.0)]
        if self.choices:
            desc.additional_constraints = f'one of {list(self.choices)}'
        return desc

    def _scalar_type(self) -> type:
        value = self.default[0] if isinstance(self.default, list) and self.default else self.default
        return type(value)

    def coerce(self, value: Any) -> Any:
        """The value as this parameter's type, or ParameterError saying why not."""
        want = self._scalar_type()
        items = value if isinstance(value, (list, tuple)) else None
        if isinstance(self.default, list) != (items is not None):
            raise ParameterError(f'{self.name}: {value!r} must be '
                                 f'{"a list" if isinstance(self.default, list) else "a scalar"}')
        out = []
        for item in (items if items is not None else [value]):
            if want is float and isinstance(item, int) and not isinstance(item, bool):
                item = float(item)
            if want is str and isinstance(item, bool):
                item = self._word_for(item)
            if not isinstance(item, want) or (want is int and isinstance(item, bool)):
                raise ParameterError(f'{self.name}: {value!r} has type {type(item).__name__}, '
                                     f'expected {want.__name__}')
            if self.range is not None and not self.range[0] <= item <= self.range[1]:
                raise ParameterError(f'{self.name}: {item!r} is outside '
                                     f'[{self.range[0]}, {self.range[1]}]')
            if self.choices is not None and item not in self.choices:
                raise ParameterError(f'{self.name}: {item!r} is not one of {list(self.choices)}')
            if self.pattern is not None and not re.fullmatch(self.pattern[0], item):
                raise ParameterError(f'{self.name}: {item!r} is not {self.pattern[1]}')
            out.append(item)
        return out if items is not None else out[0]

    def _word_for(self, flag: bool) -> str:
        """The choice an unquoted YAML word that read as `flag` meant (`off`, `N`), when exactly
        one choice reads so; otherwise ParameterError asking to quote the value."""
        words = YAML_BOOLEAN_WORDS[flag]
        meant = [choice for choice in self.choices or () if choice in words]
        if len(meant) == 1:
            return meant[0]
        raise ParameterError(f'{self.name}: {flag} is a boolean, expected a string: YAML reads '
                             'unquoted on/off, yes/no, y/n and true/false as booleans; quote '
                             f"the value, e.g. {self.name}: '{words[-1].lower()}'")


HAND_CONFIG = ParamSpec('hand_config', '', 'hand description YAML; empty = the default hand')
# As robot_state_publisher's frame_prefix: two hands in one graph publish in their own frames
# (left/uskin_index_tip) while the hand description and the URDF keep the bare names.
FRAME_PREFIX = ParamSpec('frame_prefix', '', 'put in front of every frame id this node publishes '
                         'or expects (e.g. left/ for a hand in /left); empty: the URDF names',
                         pattern=FRAME_PREFIX_PATTERN)
GRAVITY = ParamSpec('gravity', [0.0, 0.0, -9.81], 'gravity in the hand base frame (m/s^2), from '
                    'the mounting', range=(-20.0, 20.0))


def hand_parameter(params: dict) -> HandDescription:
    """The hand that `hand_config` names; a description that does not load is refused."""
    try:
        return load_hand(params['hand_config'] or None)
    except (HandConfigError, OSError) as exc:
        raise ParameterError(f'hand_config: {exc}') from None


def kinematics_parameter(hand: HandDescription, params: dict):
    """The hand's HandKinematics under `gravity`; a URDF the kinematics cannot use is refused."""
    # Imported here: pinocchio costs every node 0.2-0.4 s of start-up (python -X importtime),
    # and only the nodes that move the hand need it.
    from tacforce_ros.hand.kinematics import HandKinematics
    try:
        return HandKinematics.for_hand(hand, gravity=np.asarray(params['gravity']))
    except (HandConfigError, OSError, ValueError) as exc:
        raise ParameterError(f'hand_config/gravity: {exc}') from None


def params_files(args: Sequence[str]) -> list[Path]:
    """The files named by --params-file in the ROS arguments of a command line."""
    files, in_ros_args = [], False
    for i, arg in enumerate(args):
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg == '--params-file' and i + 1 < len(args):
            files.append(Path(args[i + 1]))
    return files


def params_file_node_keys(doc: Any, prefix: str = '') -> list[str]:
    """Node keys of a parameters YAML, namespaces joined (``/ns/node``): each path down to a
    ``ros__parameters`` mapping, as rcl_yaml_param_parser reads them."""
    if not isinstance(doc, dict):
        return []
    keys = []
    for key, value in doc.items():
        if key == 'ros__parameters':
            keys.append(prefix or '/')
        else:
            keys.extend(params_file_node_keys(value, f'{prefix}/{str(key).strip("/")}'))
    return keys


def node_key_matches(key: str, fully_qualified_name: str) -> bool:
    """rcl's rule: a node key names the node (``node``, ``/ns/node``), with ``*`` for one name
    token and ``**`` for any number of them."""
    pattern = (re.escape('/' + key.strip('/')).replace(r'/\*\*', '(/[^/]+)*')
               .replace(r'\*', '[^/]+'))
    return re.fullmatch(pattern, fully_qualified_name) is not None


def unmatched_params_files(node: Node, args: Sequence[str]) -> list[str]:
    """One message per --params-file whose node keys all miss this node: its parameters would
    silently stay at their defaults (a misspelt node key, or the wrong file)."""
    import yaml
    name = node.get_fully_qualified_name()
    messages = []
    for path in params_files(args):
        try:
            keys = params_file_node_keys(yaml.safe_load(path.read_text()))
        except (OSError, yaml.YAMLError):
            continue                # rcl itself refused an unreadable file before we got here
        if keys and not any(node_key_matches(key, name) for key in keys):
            near = difflib.get_close_matches(name, keys, n=1)
            messages.append(f'{path}: no entry for this node ({name}); its node keys are {keys}'
                            + (f' (did you mean {name!r} for {near[0]!r}?)' if near else '')
                            + ': those parameters are NOT applied, this node runs on defaults')
    return messages
