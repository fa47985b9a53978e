"""TacforceNode, the base of every tacforce_ros node: declares and checks its parameters
(nodes/parameters.py), stamps with its own clock, waits for /clock, and leaves things safe.

Time. Nodes stamp and time everything with their own clock (`now_ns()`, `create_timer`), which
follows /clock when `use_sim_time` is true (declared by rclpy itself); never time.time().
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from tacforce_ros.nodes.parameters import FRAME_PREFIX, ParameterError, ParamSpec
from tacforce_ros.nodes.realtime import REALTIME_PRIORITY, use_realtime_scheduling
from tacforce_ros.topics import relative


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


_BUILDING: list[Node] = []      # the node whose constructor ran last (half_built)


def half_built(built: Sequence[Node]) -> Node | None:
    """The node whose constructor ran last if it is not among `built` (it raised): its rclpy
    node exists and should be destroyed before the context shuts down, not left to it. (A
    refusing ft_bridge once ended with SIGSEGV after its refusal, 1 of 4 runs of
    test_nodes_bad_parameters under the suite's load; not reproduced since, 0 of 8 runs alone
    either way: the suspected cause, not a proven one.)"""
    node = _BUILDING[0] if _BUILDING else None
    return node if node is not None and all(node is not b for b in built) else None


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
        # Its rclpy node (and DDS participant) exists from here: one whose constructor raises
        # is destroyed by run_nodes before the context shuts down (half_built).
        _BUILDING[:] = [self]
        # Set by SIGINT/SIGTERM (run_nodes shares its own): waits at start-up give up on it.
        self.stop_event = StopFlag()
        self.exit_code = 0          # finish() sets it: the process's exit code when it ends
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

    def finish(self, code: int) -> None:
        """End the process after this callback (a node whose job is done, e.g. a client with
        its result), with exit code `code` (run_nodes takes the highest of its nodes')."""
        self.exit_code = max(self.exit_code, int(code))
        self.stop_event.set()

    def leave_safe(self) -> None:
        """Leave hardware and files safe; called once by run_node before the node is destroyed.
        (Not named on_shutdown: that is the lifecycle's shutdown transition.)"""
