"""What every tacforce_ros node shares: parameter specs, QoS per topic, and the main() helper.

Parameters. A node lists its parameters as a table of `ParamSpec` (name, default, description,
range or choices, read_only). `TacforceNode` declares them with a full ParameterDescriptor (so
`ros2 param describe` shows the description and range), checks every value at start-up and
refuses bad ones with one message naming each parameter, e.g. ``rate_hz: -5.0 is outside
[1.0, 1000.0]``; `run_node` logs it and exits with EXIT_BAD_PARAMETERS. An integer given for a
float parameter (``-p rate_hz:=50``) is accepted as that float. Writable (not read_only)
parameters are checked again when changed at run time.

QoS (one table, `TOPIC_QOS` in tacforce_ros/topics.py, decides per topic; `publisher_qos()` /
`subscriber_qos()` read it):
* high-rate sensor streams (/tactile/raw, /ft_sensor/wrench, /joint_states, estimates):
  publishers RELIABLE keep-last, subscribers best-effort sensor-data QoS, as REP 2003 advises:
  a reliable publisher matches both kinds of subscriber, and a best-effort subscriber never
  stalls the publisher nor gets an old sample retransmitted after a newer one;
* commands and controller state (/force_controller/desired, /force_controller/state,
  /calibration/sample): reliable both ways, keep-last 10, volatile: a dropped set-point or
  recorded sample is a real loss, and late joiners must not act on stale commands.

Time. Nodes stamp and time everything with their own clock (`now_ns()`, `create_timer`), which
follows /clock when `use_sim_time` is true (declared by rclpy itself); never time.time().

Scheduling. Nodes on the 100 Hz path (estimator, force_controller, allegro_driver) offer
`realtime_priority`: above 0 every thread of the process (rclpy's and the DDS layer's) runs
SCHED_FIFO at that priority, as ros2_control's real-time threads do, so a frame is not kept
waiting behind ordinary processes; without the right (CAP_SYS_NICE or an rtprio limit) the node
says so and runs normally. 0 (the default) leaves the normal scheduler.

Distros. Uses only API present in Humble, Jazzy and Kilted; `SignalHandlerOptions` (Humble+) is
imported defensively.
"""
from __future__ import annotations

import argparse
import difflib
import os
import re
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.executors import Executor, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.utilities import remove_ros_args
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)

from tacforce_ros.hand.description import (FRAME_PREFIX_PATTERN, HandConfigError, HandDescription,
                                           load_hand)
from tacforce_ros.topics import PUBLISHER_DEPTH, SENSOR, qos_kind, relative

EXIT_OK = 0
EXIT_FAILURE = 1          # an unexpected exception while running
EXIT_BAD_PARAMETERS = 2   # refused at start-up: the log names each bad parameter

SENSOR_PUBLISHER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=PUBLISHER_DEPTH,
                                  reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.VOLATILE)
SENSOR_SUBSCRIBER_QOS = qos_profile_sensor_data
RELIABLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=PUBLISHER_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)

def publisher_qos(topic: str) -> QoSProfile:
    return SENSOR_PUBLISHER_QOS if qos_kind(topic) == SENSOR else RELIABLE_QOS


def subscriber_qos(topic: str, depth: int | None = None) -> QoSProfile:
    """Subscriber QoS of `topic`; `depth` sets the history, keeping the reliability policy:
    deeper for a consumer that must ride out CPU hiccups without losing samples (a recorder),
    1 for one that acts on the newest sample only (a controller: rclpy takes a queue's oldest
    message first, one per executor pass, so a history of several feeds it old states)."""
    base = SENSOR_SUBSCRIBER_QOS if qos_kind(topic) == SENSOR else RELIABLE_QOS
    if depth is None:
        return base
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=base.reliability, durability=base.durability)


class ParameterError(ValueError):
    """Parameter values a node refuses; the message names every offending parameter."""


class StopFlag:
    """Set by a node process's SIGINT/SIGTERM handler, read by the waits of its start-up.

    A signal handler runs in the main thread between two bytecodes, possibly while that thread
    holds a lock: a threading.Event's set() takes its lock, and would wait for ever on a thread
    stopped inside that Event's own wait(). This sets a plain attribute, and wait() polls it."""

    POLL_S = 0.02

    def __init__(self) -> None:
        self._set = False

    def set(self) -> None:
        self._set = True

    def is_set(self) -> bool:
        return self._set

    def wait(self, timeout: float) -> bool:
        """Sleep until set or `timeout` s have passed; whether it is set."""
        deadline = time.monotonic() + timeout
        while not self._set and (left := deadline - time.monotonic()) > 0:
            time.sleep(min(self.POLL_S, left))
        return self._set


class StopRequested(Exception):
    """SIGINT or SIGTERM came while the node was still starting (waiting for its clock or its
    device): the process ends cleanly instead of finishing the wait."""


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


REALTIME_PRIORITY = ParamSpec(
    'realtime_priority', 0, 'SCHED_FIFO priority (1-98) of all of this process\'s threads; '
    '0 = the normal scheduler. Needs CAP_SYS_NICE or an rtprio limit, else a warning',
    range=(0, 98))


def use_realtime_scheduling(priority: int) -> None:
    """SCHED_FIFO at `priority` for every thread of this process (threads started later by them
    inherit it); 0 returns them to the normal scheduler. OSError when the system refuses (no
    right, or not Linux)."""
    if not hasattr(os, 'sched_setscheduler'):
        raise OSError('SCHED_FIFO needs Linux')
    policy = os.SCHED_FIFO if priority > 0 else os.SCHED_OTHER
    param = os.sched_param(priority)
    for tid in os.listdir('/proc/self/task'):
        try:
            os.sched_setscheduler(int(tid), policy, param)
        except ProcessLookupError:   # a thread that ended meanwhile
            continue


class TacforceNode(Node):
    """Node base: declares and checks `PARAMETERS`, offers `now_ns()`, `on_built()` and
    `leave_safe()`.

    Subclasses set NODE_NAME and PARAMETERS; after `super().__init__()`, `self.params[name]`
    holds each checked value.
    """

    NODE_NAME = 'tacforce_node'
    PARAMETERS: Sequence[ParamSpec] = ()

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NODE_NAME, **kwargs)
        # Set by SIGINT/SIGTERM (run_nodes shares its own): waits at start-up give up on it.
        self.stop_event = StopFlag()
        self.samples_before_clock = 0
        self._clock_seen = False
        self.same_stamp: dict[str, int] = {}
        self._last_stamp: dict[str, int] = {}
        self._specs = {spec.name: spec for spec in self.PARAMETERS}
        self.params = self._declare_checked()
        self.add_on_set_parameters_callback(self._check_change)
        priority = self.params.get(REALTIME_PRIORITY.name, 0)
        if priority > 0:
            try:
                use_realtime_scheduling(priority)
                self.get_logger().info(f'threads run SCHED_FIFO at priority {priority}')
            except OSError as exc:
                self.get_logger().warning(f'realtime_priority {priority} not applied ({exc}); '
                                          'running on the normal scheduler')

    def _declare_checked(self) -> dict[str, Any]:
        # rclpy offers no public read of command-line / file overrides before declaring; this
        # dict exists unchanged in Humble, Jazzy and Kilted. Checking it first lets us report
        # our own message, and declare the coerced value (int -> float) instead of failing.
        overrides = getattr(self, '_parameter_overrides', {})
        values, problems = {}, []
        for spec in self.PARAMETERS:
            given = overrides[spec.name].value if spec.name in overrides else spec.default
            try:
                values[spec.name] = spec.coerce(given)
            except ParameterError as exc:
                problems.append(str(exc))
                continue
            self.declare_parameter(spec.name, values[spec.name], spec.descriptor(),
                                   ignore_override=True)
        if problems:
            raise ParameterError('; '.join(problems))
        unknown = sorted(name for name in overrides
                         if name not in self._specs and not self.has_parameter(name)
                         and not name.startswith('qos_overrides.'))
        if unknown:     # a typo in a parameter file would otherwise pass silently
            self.get_logger().warning(f'ignoring parameters this node does not have: {unknown}')
        return values

    def _check_change(self, parameters: list[Parameter]) -> SetParametersResult:
        for param in parameters:
            spec = self._specs.get(param.name)
            if spec is None:
                continue
            try:
                self.params[param.name] = spec.coerce(param.value)
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def frame(self, name: str) -> str:
        """A frame of the hand description or URDF as this node publishes and expects it: with
        its `frame_prefix` (FRAME_PREFIX) in front, for nodes that have one."""
        return self.params.get(FRAME_PREFIX.name, '') + name

    def topic_name(self, topic: str) -> str:
        """`topic` (a TOPIC_* name) as this node resolves it, namespace included: for log lines."""
        return self.resolve_topic_name(relative(topic))

    def now_ns(self) -> int:
        """Node clock time (sim time when use_sim_time is true), integer nanoseconds."""
        return self.get_clock().now().nanoseconds

    def stamp_ns(self) -> int | None:
        """now_ns() for stamping a sample, or None while the clock is not valid yet: under
        use_sim_time it reads 0 until the first /clock, and a sample stamped 0 would pose as the
        oldest of the session. Drivers drop such samples; they are counted, and logged once."""
        now = self.now_ns()
        if now <= 0:
            self.samples_before_clock += 1
            return None
        if not self._clock_seen:
            self._clock_seen = True
            if self.samples_before_clock:
                self.get_logger().info(f'clock valid at {now * 1e-9:.3f} s; dropped '
                                       f'{self.samples_before_clock} samples that came before it')
        return now

    def new_stamp_ns(self, stream: str) -> int | None:
        """stamp_ns() for a sample of `stream`, or None (counted in `same_stamp[stream]`) when
        the clock has not moved since that stream's previous sample: under sim time a device
        that samples faster than the simulator steps, or while simulated time is held, repeats
        one instant's state, and a second message with that stamp would say two instants where
        there was one. With a hardware clock time always moves and nothing is dropped."""
        now = self.stamp_ns()
        if now is None:
            return None
        if now <= self._last_stamp.get(stream, 0):
            self.same_stamp[stream] = self.same_stamp.get(stream, 0) + 1
            return None
        self._last_stamp[stream] = now
        return now

    def wait_for_clock(self, timeout: float) -> None:
        """Under use_sim_time, spin this node until its clock reads simulated time (the first
        /clock arrived); RuntimeError after `timeout` wall seconds. Returns at once otherwise."""
        if not self.get_parameter('use_sim_time').value:
            return
        executor = SingleThreadedExecutor()
        executor.add_node(self)
        deadline = time.monotonic() + timeout
        try:
            while self.now_ns() <= 0:
                if self.stop_event.is_set():
                    raise StopRequested('stopped while waiting for /clock')
                if time.monotonic() > deadline:
                    raise RuntimeError(f'no /clock within {timeout:g} s (use_sim_time is true: '
                                       'is the simulator running?)')
                executor.spin_once(timeout_sec=0.05)
        finally:
            executor.remove_node(self)
            executor.shutdown()

    def on_built(self) -> None:
        """Called once by run_node right after building the node, before spinning (a managed
        driver's autostart)."""

    def leave_safe(self) -> None:
        """Leave hardware and files safe; called once by run_node before the node is destroyed.
        (Not named on_shutdown: that is the lifecycle's shutdown transition.)"""


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


def _init_without_rclpy_signal_handlers(args: Sequence[str] | None) -> None:
    try:    # Humble+: let run_node own SIGINT/SIGTERM so leave_safe always runs first
        from rclpy.signals import SignalHandlerOptions
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except (ImportError, TypeError):
        rclpy.init(args=args)


def parse_cli(node_cls: type[TacforceNode], args: Sequence[str]) -> None:
    """--help for a node: its docstring and parameter table; ROS arguments pass through."""
    lines = [f'  {s.name} (default {s.default!r}'
             + (f', range {list(s.range)}' if s.range else '')
             + (f', one of {list(s.choices)}' if s.choices else '')
             + (', writable' if not s.read_only else '') + f'): {s.description}'
             for s in node_cls.PARAMETERS]
    parser = argparse.ArgumentParser(
        prog=Path(args[0]).name if args else None, description=node_cls.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='parameters (set with --ros-args -p name:=value or --params-file FILE):\n'
        + '\n'.join(lines))
    parser.parse_args(remove_ros_args(list(args))[1:])


def events_executor() -> Executor:
    """rclpy's EventsExecutor (Jazzy and later), SingleThreadedExecutor where it is missing."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:         # Humble
        return SingleThreadedExecutor()
    return EventsExecutor()


def run_node(node_cls: type[TacforceNode], args: Sequence[str] | None = None, *,
             threads: int = 1, executor: Callable[[], Executor] | None = None) -> int:
    """main() of a node: --help, rclpy init, build the node, `on_built()`, spin until
    SIGINT/SIGTERM or rclpy shutdown, then `leave_safe()`, destroy and shut down. Returns the
    exit code (EXIT_*; `sys.exit(run_node(MyNode))`).

    threads > 1 spins a MultiThreadedExecutor (needed when a callback waits on another one,
    e.g. a service handler that waits for a subscription); `executor`, if given, makes the
    executor instead (called once the node exists, e.g. rclpy's EventsExecutor); otherwise
    single-threaded.
    """
    args = list(sys.argv if args is None else args)
    parse_cli(node_cls, args)
    return run_nodes([(node_cls, None)], args, threads=threads, executor=executor)


def run_nodes(parts: Sequence[tuple[type[TacforceNode], Sequence[str] | None]],
              args: Sequence[str], *, threads: int = 1,
              executor: Callable[[], Executor] | None = None) -> int:
    """run_node for one or several nodes in this process, on one executor: each part is a node
    class and its own ROS arguments (None: the process's, `args`, which rclpy is initialised
    with). Built in order; any node's error ends them all; leave_safe() in reverse order.

    SIGINT and SIGTERM are handled from before rclpy.init on, and stay so (the process ends
    right after: nodes/entry.py). One that comes while the first node is being built ends the
    process there: nothing is open yet that leave_safe would close (nodes open devices and
    files in on_built), and a constructor has no waits that look at the stop. Later, it sets
    the stop every wait of a start-up, and the spin loop, look at."""
    stop = StopFlag()
    building = [False]

    def on_signal(signum: int, _frame) -> None:
        stop.set()
        if building[0] and not nodes:
            os.write(2, f'{parts[0][0].NODE_NAME}: stopped by {signal.Signals(signum).name} '
                     'while starting\n'.encode())
            os._exit(EXIT_OK)

    nodes: list[TacforceNode] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    _init_without_rclpy_signal_handlers(args)
    spinner = None
    logger = rclpy.logging.get_logger(parts[0][0].NODE_NAME)
    code = EXIT_OK
    try:
        try:
            for node_cls, node_args in parts:
                logger = rclpy.logging.get_logger(node_cls.NODE_NAME)
                try:
                    if stop.is_set():
                        raise StopRequested('stopped while starting')
                    building[0] = True
                    try:
                        node = (node_cls() if node_args is None else
                                node_cls(cli_args=list(node_args), use_global_arguments=False))
                    finally:
                        building[0] = False
                    nodes.append(node)
                    node.stop_event = stop
                    node.on_built()
                except ParameterError as exc:
                    logger.fatal(f'refusing to start: {exc}')
                    code = EXIT_BAD_PARAMETERS
                    return code
                except StopRequested as exc:
                    logger.info(f'{exc}: not started')
                    return code
                for message in unmatched_params_files(node, args if node_args is None
                                                      else node_args):
                    node.get_logger().warning(message)
            spinner = (executor() if executor is not None
                       else MultiThreadedExecutor(num_threads=threads) if threads > 1
                       else SingleThreadedExecutor())
            for node in nodes:
                spinner.add_node(node)
            # Short spin slices: a signal only sets `stop`, which is seen within 0.1 s.
            while not stop.is_set() and rclpy.ok():
                spinner.spin_once(timeout_sec=0.1)
        except Exception as exc:    # noqa: BLE001 - report, still leave things safe below
            logger.fatal(f'stopped by an error: {type(exc).__name__}: {exc}')
            code = EXIT_FAILURE
    finally:
        try:
            for node in reversed(nodes):
                try:
                    node.leave_safe()
                except Exception as exc:    # noqa: BLE001 - the others must still be left safe
                    node.get_logger().fatal(f'shutdown failed: {type(exc).__name__}: {exc}')
                    code = EXIT_FAILURE
        finally:
            if spinner is not None:
                spinner.shutdown()      # lets go of the nodes' handles first
            for node in nodes:
                node.destroy_node()
            rclpy.try_shutdown()
    return code
