"""A tool's view of other processes' nodes through its own ROS node (bench_stop's): whether
/clock arrives, whether a node answers, and lifecycle transitions asked of it."""
from __future__ import annotations

import time

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.srv import GetParameters
from rclpy.qos import qos_profile_sensor_data
from rosgraph_msgs.msg import Clock


class GraphProbe:
    """A tool's own ROS node for watching and driving other processes' nodes: /clock arriving,
    a node answering (a live process), lifecycle transitions."""

    def __init__(self, name: str) -> None:
        rclpy.init()
        self.node = rclpy.create_node(name)
        self.clock_seen = 0
        self.node.create_subscription(Clock, '/clock', self._on_clock, qos_profile_sensor_data)

    def _on_clock(self, _msg) -> None:
        self.clock_seen += 1

    def spin_until(self, done, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not done():
            if time.monotonic() >= deadline:
                return False
            rclpy.spin_once(self.node, timeout_sec=0.02)
        return True

    def answers(self, name: str, timeout: float, running) -> bool:
        """Node `name` answers its parameter service within `timeout` while `running()`: a live
        process (a killed one stays in the graph's node list until its DDS lease runs out)."""
        client = self.node.create_client(GetParameters, f'/{name}/get_parameters')
        deadline = time.monotonic() + timeout
        try:
            while time.monotonic() < deadline and running():
                if self._call(client, GetParameters.Request(names=['use_sim_time']),
                              min(deadline, time.monotonic() + 2.0), resend=True) is not None:
                    return True
            return False
        finally:
            self.node.destroy_client(client)

    def lifecycle(self, name: str, target: str, timeout: float) -> str:
        """Drive node `name` from unconfigured towards `target` (inactive or active); the state
        it reached ('unknown' when it does not answer in time)."""
        steps = ([Transition.TRANSITION_CONFIGURE]
                 + ([Transition.TRANSITION_ACTIVATE] if target == 'active' else []))
        return self.transitions(name, steps, timeout)

    def transitions(self, name: str, steps: list[int], timeout: float) -> str:
        """Ask node `name` for the lifecycle transitions `steps` in turn (stopping at one that
        fails); the state it is in then ('unknown' when it does not answer in time)."""
        # The change_state client is made before the get_state one, so a get_state that was
        # answered proves the server matched change_state's response reader too (rmw_fastrtps
        # drops a response to a client it has not matched yet).
        change = self.node.create_client(ChangeState, f'/{name}/change_state')
        get = self.node.create_client(GetState, f'/{name}/get_state')
        deadline = time.monotonic() + timeout
        try:
            state = self._call(get, GetState.Request(), deadline, resend=True)
            for step in steps:
                if state is None:
                    break
                answer = self._call(change, ChangeState.Request(transition=Transition(id=step)),
                                    deadline, resend=False)
                if answer is None or not answer.success:
                    break
            reached = self._call(get, GetState.Request(), deadline, resend=True)
            return reached.current_state.label if reached is not None else 'unknown'
        finally:
            self.node.destroy_client(change)
            self.node.destroy_client(get)

    def _call(self, client, request, deadline: float, resend: bool):
        if not self.spin_until(client.service_is_ready, max(0.0, deadline - time.monotonic())):
            return None
        futures = []
        while time.monotonic() < deadline:
            futures.append(client.call_async(request))
            wait = 2.0 if resend else deadline - time.monotonic()
            if self.spin_until(lambda: any(f.done() for f in futures), max(0.0, wait)):
                return next(f.result() for f in futures if f.done())
        return None

    def close(self) -> None:
        self.node.destroy_node()
        rclpy.try_shutdown()
