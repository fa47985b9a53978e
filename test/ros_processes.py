"""Start installed executables and helper scripts as real processes for ROS 2 tests."""
from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import sysconfig
import time

from tacforce_ros.bringup.processes import executable  # noqa: F401  (the tests' helper too)


def ros_env(domain_id: int) -> dict[str, str]:
    """Environment of a child on its own DDS domain, discovery limited to this host."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['PYTHONUNBUFFERED'] = '1'
    return env


def unique_domain_id(offset: int = 0) -> int:
    """A DDS domain for this test process (0..101 are valid for Fast DDS on one host)."""
    return 1 + (os.getpid() + offset) % 100


def start(args: list[str], domain_id: int, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([str(a) for a in args], env=ros_env(domain_id),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kwargs)


def end(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """SIGINT, then kill if needed."""
    if proc.poll() is None:
        proc.send_signal(2)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=timeout)


def stop(proc: subprocess.Popen, timeout: float = 10.0) -> str:
    """SIGINT, then kill if needed; returns what the process printed."""
    end(proc, timeout)
    return proc.stdout.read() if proc.stdout else ''


PYTHON = sys.executable
PURELIB = sysconfig.get_paths()['purelib']


def spin_until(node, done, timeout: float) -> bool:
    """Spin `node` until done() is true or `timeout` seconds pass; returns done()."""
    import rclpy
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    return done()


def call_service(node, srv_type, name: str, request, timeout: float = 60.0,
                 resend_after: float | None = None):
    """Call a service from a test node, waiting (bounded) for it to appear and answer.

    One client per node and service, kept for the node's life: rmw_fastrtps drops a response
    when the server has not yet matched the client's response reader (it waits ~100 ms for it:
    ros2/rmw_fastrtps#390, #467), which a stalling host makes likely on a new client's first
    call. `resend_after` (idempotent requests only): send again if no answer came within that
    many seconds; a first answered call then proves the client's path for the next ones."""
    clients = node.__dict__.setdefault('_test_service_clients', {})
    client = clients.get(name)
    if client is None:
        client = clients[name] = node.create_client(srv_type, name)
    deadline = time.monotonic() + timeout
    assert spin_until(node, client.service_is_ready, timeout), f'{name} never appeared'
    return _answer(node, client, name, request, deadline, resend_after)


def _answer(node, client, name: str, request, deadline: float, resend_after: float | None):
    """Send `request` on a ready client until answered or `deadline` (monotonic) passes,
    again every `resend_after` seconds when given; the first answer."""
    futures = []
    while time.monotonic() < deadline and not any(f.done() for f in futures):
        futures.append(client.call_async(request))
        wait = deadline - time.monotonic() if resend_after is None else resend_after
        spin_until(node, lambda: any(f.done() for f in futures), max(0.0, wait))
    answered = [f for f in futures if f.done()]
    assert answered, f'{name} did not answer ({len(futures)} request(s) sent)'
    return answered[0].result()


def call_service_once(node, srv_type, name: str, request, timeout: float = 60.0):
    """Call a service whose request must not be sent twice (it starts or restarts something).

    A new client's first response can be dropped (see call_service), and resending is no cure
    here. So this client is created first, then one for the server node's get_parameters,
    which is called (idempotent: resent until answered). The test node announced the two
    clients' response readers in that order on one reliable discovery writer, which delivers
    in order: a server that answered get_parameters has matched this client's reader too."""
    from rcl_interfaces.srv import GetParameters
    server_node = name.rsplit('/', 1)[0]
    client = node.create_client(srv_type, name)
    proof = node.create_client(GetParameters, f'{server_node}/get_parameters')
    try:
        deadline = time.monotonic() + timeout
        assert spin_until(node, lambda: client.service_is_ready() and proof.service_is_ready(),
                          timeout), f'{name} never appeared'
        _answer(node, proof, f'{server_node}/get_parameters', GetParameters.Request(),
                deadline, resend_after=2.0)
        return _answer(node, client, name, request, deadline, resend_after=None)
    finally:
        node.destroy_client(proof)
        node.destroy_client(client)


@contextlib.contextmanager
def rclpy_node(name: str, domain_id: int):
    """An rclpy context on `domain_id` with one node, shut down on exit."""
    import rclpy
    rclpy.init(domain_id=domain_id)
    node = rclpy.create_node(name)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown()


class OutputLines:
    """Reads a started process's output in a thread, so a test can wait for a line while the
    process runs; `stop()` ends the process and returns everything it printed."""

    def __init__(self, proc: subprocess.Popen) -> None:
        import threading
        self.proc = proc
        self.lines: list[tuple[float, str]] = []     # (monotonic time read, line)
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append((time.monotonic(), line))

    def wait_for(self, text: str, timeout: float, since: float = 0.0) -> float | None:
        """Monotonic time of the first line containing `text` read at or after `since`,
        waiting at most `timeout` s."""
        deadline = time.monotonic() + timeout
        while True:
            found = next((t for t, line in list(self.lines) if t >= since and text in line),
                         None)
            if found is not None or time.monotonic() > deadline:
                return found
            time.sleep(0.01)

    def text(self) -> str:
        return ''.join(line for _, line in list(self.lines))

    def stop(self, timeout: float = 10.0) -> str:
        end(self.proc, timeout)
        self._thread.join(timeout)
        return self.text()
